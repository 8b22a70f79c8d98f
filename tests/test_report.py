"""Fill reports: the JSON validates against its documented schema; the HTML page is self-contained and complete."""

from __future__ import annotations

import json
from html.parser import HTMLParser
from types import SimpleNamespace

import numpy as np
import pytest

from mocapfill.errors import MocapfillError
from mocapfill.markers import MarkerData
from mocapfill.methods.base import finish
from mocapfill.report import build_fill_report, load_schema, write_report


# A small JSON Schema validator for the keywords our schema uses (jsonschema is not a dependency).
_TYPES = {
    "object": lambda v: isinstance(v, dict),
    "array": lambda v: isinstance(v, list),
    "string": lambda v: isinstance(v, str),
    "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
    "number": lambda v: isinstance(v, (int, float)) and not isinstance(v, bool),
    "boolean": lambda v: isinstance(v, bool),
    "null": lambda v: v is None,
}


def validate(value, schema, where="$"):
    """Raise AssertionError naming the first place where ``value`` breaks ``schema``."""
    known = {"$schema", "$id", "title", "description", "type", "required", "properties", "additionalProperties",
             "items", "enum", "const", "minimum", "maximum", "minItems", "maxItems"}
    assert set(schema) <= known, f"validator does not know {set(schema) - known}"
    if "type" in schema:
        types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
        assert any(_TYPES[t](value) for t in types), f"{where}: {value!r} is not {types}"
    if "const" in schema:
        assert value == schema["const"], f"{where}: {value!r} != {schema['const']!r}"
    if "enum" in schema:
        assert value in schema["enum"], f"{where}: {value!r} not in {schema['enum']}"
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if "minimum" in schema:
            assert value >= schema["minimum"], f"{where}: {value} < {schema['minimum']}"
        if "maximum" in schema:
            assert value <= schema["maximum"], f"{where}: {value} > {schema['maximum']}"
    if isinstance(value, dict):
        for key in schema.get("required", []):
            assert key in value, f"{where}: missing {key!r}"
        props = schema.get("properties", {})
        for key, item in value.items():
            if key in props:
                validate(item, props[key], f"{where}.{key}")
            elif schema.get("additionalProperties", True) is False:
                raise AssertionError(f"{where}: unexpected key {key!r}")
    if isinstance(value, list):
        if "minItems" in schema:
            assert len(value) >= schema["minItems"], where
        if "maxItems" in schema:
            assert len(value) <= schema["maxItems"], where
        if "items" in schema:
            for i, item in enumerate(value):
                validate(item, schema["items"], f"{where}[{i}]")


def _clip(n_frames=120, n_markers=6, seed=0):
    """A smooth synthetic capture, positions (n_frames, n_markers, 3) in mm, first frame 10."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames)[:, None, None] / 60.0
    base = rng.normal(0, 200, (1, n_markers, 3))
    pos = base + 50 * np.sin(2 * np.pi * 0.7 * t + rng.uniform(0, 6, (1, n_markers, 3)))
    return MarkerData(pos, [f"M{i}" for i in range(n_markers)], 60.0, "mm", first_frame=10, path="clip.c3d")


def _fill(data, leave=()):
    """A fill of ``data`` (linear interpolation written here, not a registered method) leaving ``leave`` markers'
    gaps unfilled; std given, objective of three iterations, per-gap methods in info."""
    pos = data.positions
    est = pos.copy()
    t = np.arange(data.n_frames)
    for m in range(data.n_markers):
        ok = ~np.isnan(pos[:, m, 0])
        for k in range(3):
            est[:, m, k] = np.interp(t, t[ok], pos[ok, m, k])
        if m in leave:
            est[~ok, m] = np.nan
    std = np.full(pos.shape[:2], 2.0)
    return finish(pos, est, std=std, n_iter=3, converged=False, objective=[10.0, 5.0, float("nan")],
                  info={"gap_methods": [{"marker": "M1", "start": 20, "length": 15, "method": "dynammo", "reason": "long gap",
                                         "review": True},
                                        {"marker": 2, "first_frame": 60, "method": "pca"}],
                        "hidden": 16})


@pytest.fixture
def case():
    clean = _clip()
    pos = clean.positions.copy()
    pos[20:35, 1] = np.nan  # interior gap
    pos[50:58, 2] = np.nan  # interior gap
    pos[0:5, 3] = np.nan  # gap at the start, left unfilled below
    rejected = np.zeros(pos.shape[:2], bool)
    rejected[70:72, 4] = True
    pos[rejected] = np.nan
    data = clean.with_positions(pos)
    result = _fill(data, leave=(3,))
    bones = SimpleNamespace(pairs=np.array([[0, 1], [1, 2], [4, 5], [0, 5]]),
                            lengths=np.array([100.0, 120.0, 90.0, 80.0]))
    report = build_fill_report(data, result, method="auto", settings={"hidden": 16, "seed": np.int64(3)},
                               seconds=0.25, input_path="clip.c3d", output_path="out.c3d", bones=bones,
                               rejected=rejected, smoothed=True)
    return SimpleNamespace(data=data, result=result, bones=bones, report=report, rejected=rejected)


def test_json_report_validates_and_holds_the_facts(case, tmp_path):
    path = tmp_path / "r.json"
    write_report(case.report, path, data=case.data, result=case.result, bones=case.bones)
    doc = json.loads(path.read_text())
    validate(doc, load_schema())
    s = doc["summary"]
    assert (s["frames"], s["markers"], s["method"], s["smoothed"]) == (120, 6, "auto", True)
    assert s["missing_samples"] == 15 + 8 + 5 + 2 and s["filled_samples"] == 25
    assert s["convergence"] == {"n_iter": 3, "converged": False, "objective": [10.0, 5.0, None]}
    assert s["settings"] == {"hidden": 16, "seed": 3}
    by_marker = {g["marker"]: g for g in doc["gaps"]}
    assert by_marker["M1"]["first_frame"] == 30 and by_marker["M1"]["length"] == 15  # file numbering
    assert by_marker["M1"]["method"] == "dynammo" and by_marker["M2"]["method"] == "pca"
    assert by_marker["M1"]["mean_std"] == 2.0 and by_marker["M1"]["reason"] == "long gap"
    assert by_marker["M2"]["reason"] is None
    assert by_marker["M1"]["review"] and not by_marker["M2"]["review"] and s["review_gaps"] == 1
    assert by_marker["M3"]["status"] == "unfilled" and by_marker["M3"]["at_start"]
    assert by_marker["M4"]["rejected_samples"] == 2
    assert doc["unfilled"] == [{"marker": "M3", "first_frame": 10, "length": 5}]
    assert doc["rejected"] == [{"marker": "M4", "frame": 80}, {"marker": "M4", "frame": 81}]
    assert s["methods_used"] == ["dynammo", "pca"]
    touching = {tuple(b["markers"]) for b in doc["bones"]["touching_filled"]}
    assert touching == {("M0", "M1"), ("M1", "M2"), ("M4", "M5")}


def test_json_report_without_bones_std_or_gaps_validates():
    data = _clip()
    result = finish(data.positions, data.positions)
    report = build_fill_report(data, result, method="linear", settings=None, seconds=0.0, input_path=None,
                               output_path=None)
    validate(json.loads(json.dumps(report, allow_nan=False)), load_schema())
    assert report["gaps"] == [] and report["bones"] is None and report["summary"]["percent_filled"] == 100.0


class _Collector(HTMLParser):
    def __init__(self):
        super().__init__()
        self.figures = []
        self.external = []
        self.svgs = 0

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "figure":
            self.figures.append((attrs.get("class", ""), attrs.get("data-name")))
        if tag == "svg":
            self.svgs += 1
        for key in ("src", "href"):
            value = attrs.get(key) or ""
            if value and not value.startswith("#") and tag != "svg":
                self.external.append(value)


def test_html_report_is_self_contained_with_one_plot_per_filled_marker(case, tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "r.html"
    write_report(case.report, path, data=case.data, result=case.result, bones=case.bones)
    text = path.read_text()
    parser = _Collector()
    parser.feed(text)
    parser.close()
    markers = [name for cls, name in parser.figures if "marker-plot" in cls]
    assert markers == ["M1", "M2", "M4"]  # M3 was left unfilled
    assert len([1 for cls, _ in parser.figures if "bone-plot" in cls]) == 3
    assert any("objective-plot" in cls for cls, _ in parser.figures)
    assert parser.svgs == len(parser.figures)
    assert not [u for u in parser.external if u.startswith(("http:", "https:", "//"))]
    assert "<script src" not in text and 'id="player"' in text  # the player is the one (inline) script
    assert "NOT converged" in text and "still missing" in text
    assert "1 gap to review" in text and "M1 30-44" in text  # the gap the method flagged, in file numbering


@pytest.mark.slow
def test_html_report_plots_drawn_on_two_processes_are_the_same_page(case, tmp_path):
    # The trajectory and bone plots (tenths of a second of matplotlib each) may be drawn on forked processes: the
    # page is the same, figure for figure and in the same order.
    pytest.importorskip("matplotlib")
    one, two = tmp_path / "one.html", tmp_path / "two.html"
    write_report(case.report, one, data=case.data, result=case.result, bones=case.bones, jobs=1)
    write_report(case.report, two, data=case.data, result=case.result, bones=case.bones, jobs=2)
    assert one.read_text() == two.read_text() and one.read_text().count("<svg") >= 6


def test_html_report_caps_plots_and_says_what_was_left_out(case, tmp_path):
    pytest.importorskip("matplotlib")
    path = tmp_path / "r.html"
    write_report(case.report, path, data=case.data, result=case.result, bones=case.bones, max_markers=2,
                 max_bones=1)
    parser = _Collector()
    parser.feed(path.read_text())
    markers = [name for cls, name in parser.figures if "marker-plot" in cls]
    assert markers == ["M1", "M2"]  # the two with the most filled samples
    assert "1 more not plotted: M4" in path.read_text()
    assert len([1 for cls, _ in parser.figures if "bone-plot" in cls]) == 1
    assert "2 more bones not plotted" in path.read_text()


def test_html_report_without_matplotlib_is_a_one_line_error(case, tmp_path, monkeypatch):
    import builtins

    real_import = builtins.__import__

    def fake_import(name, *args, **kwargs):
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ImportError(name)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", fake_import)
    with pytest.raises(MocapfillError, match=r"HTML reports need matplotlib: pip install 'mocapfill\[report\]'"):
        write_report(case.report, tmp_path / "r.html", data=case.data, result=case.result)
    assert not (tmp_path / "r.html").exists()
    write_report(case.report, tmp_path / "r.json", data=case.data, result=case.result)  # JSON never needs it


def test_unknown_report_extension_is_an_error(case, tmp_path):
    with pytest.raises(MocapfillError, match=r"r\.txt.*\.json or \.html"):
        write_report(case.report, tmp_path / "r.txt", data=case.data, result=case.result)


def test_importing_report_leaves_matplotlib_alone():
    import subprocess
    import sys

    code = "import sys, mocapfill.report; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"


def test_reports_of_a_real_fill(sample_data, tmp_path):
    pytest.importorskip("matplotlib")
    import mocapfill
    from mocapfill.api import fill

    full = mocapfill.read(sample_data / "85_02.c3d")
    clean = MarkerData(full.positions[:200].copy(), full.labels, full.rate, full.units, full.first_frame,
                       path=str(sample_data / "85_02.c3d"))
    pos = clean.positions.copy()
    short = [label.split(":")[-1] for label in clean.labels]
    for name, (a, b) in {"RKNE": (50, 90), "RSHN": (50, 90), "LELB": (10, 20)}.items():
        pos[a:b, short.index(name)] = np.nan
    data = clean.with_positions(pos)
    result = fill(data, "spline")
    try:
        from mocapfill.bones import estimate_bones

        bones = estimate_bones(pos, units=data.units, labels=data.labels)
    except ImportError:  # pragma: no cover - the bones module lands separately
        bones = None
    report = build_fill_report(data, result, method="spline", settings={}, seconds=0.01, input_path=data.path,
                               output_path=str(tmp_path / "out.c3d"), bones=bones)
    write_report(report, tmp_path / "r.json", data=data, result=result, bones=bones)
    validate(json.loads((tmp_path / "r.json").read_text()), load_schema())
    write_report(report, tmp_path / "r.html", data=data, result=result, bones=bones, max_bones=4)
    parser = _Collector()
    parser.feed((tmp_path / "r.html").read_text())
    markers = [name for cls, name in parser.figures if "marker-plot" in cls]
    assert [m.split(":")[-1] for m in markers] == ["RKNE", "RSHN", "LELB"]  # file order
    if bones is not None:
        n_bones = len([1 for cls, _ in parser.figures if "bone-plot" in cls])
        assert n_bones == min(4, len(report["bones"]["touching_filled"]))


def test_band_outline_thins_each_filled_stretch_and_keeps_its_ends():
    # The +-2 std band is drawn from about max_points samples: each filled stretch keeps its first and last frame
    # (a one-frame stretch stays), stretches are kept apart by one NaN, and each point is the fill and 2 sd there.
    from mocapfill.report.plots import band_outline

    frames = np.arange(100, 1100)
    centre = np.linspace(0.0, 1.0, 1000)
    sd = np.full(1000, np.nan)
    sd[10] = 1.0
    sd[200:900] = 2.0
    x, mid, half = band_outline(frames, centre, sd, max_points=50)
    assert np.isnan(x).sum() == 1 and len(x) <= 50 + 3
    assert 110 in x and 300 in x and 999 in x
    finite = np.isfinite(x)
    rows = (x[finite] - 100).astype(int)
    np.testing.assert_array_equal(half[finite], 2.0 * sd[rows])
    np.testing.assert_array_equal(mid[finite], centre[rows])
