"""`mocapfill evaluate CLEAN_FILE`: hide known samples, fill them with each method, score against the truth.

People's output (progress, tables) goes to stderr; ``--json`` / ``--csv`` put every trial on stdout.
"""

from __future__ import annotations

import json
import sys
import warnings

import click
import numpy as np
from rich.table import Table

from ..errors import MethodError, MocapfillError
from . import cli
from .bones import parse_length
from .common import ReadOptions, input_options, console, quiet_option, read_input, show_warnings

PROTOCOL_CHOICES = ("marker", "limb", "blackout", "random", "dense", "segment")


def _parse_value(text: str):
    """An option value from the command line: int, float, true/false/none, else the string."""
    low = text.lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    if low in ("none", "null"):
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def _parse_options(pairs: tuple[str, ...]) -> dict:
    out = {}
    for item in pairs:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise click.BadParameter(f"{item!r} is not KEY=VALUE", param_hint="'--option'")
        out[key.strip().replace("-", "_")] = _parse_value(value.strip())
    return out


def _check_option_types(pairs: tuple[str, ...], options: dict, names: list[str]) -> None:
    """A ``-o`` value of the wrong type for a method that takes the option (``-o max_iter=abc`` for dynammo): one
    line naming the option as typed, before the file is read."""
    from ..methods import get_method

    typed = {item.partition("=")[0].strip().replace("-", "_"): item for item in pairs}
    for name in names:
        for key, value in options.items():
            problem = get_method(name).option_problem(key, value)
            if problem:
                raise click.ClickException(f"-o {typed[key]}: {problem}")


def _default_methods(given: set[str] = frozenset()) -> tuple[list[str], list[str]]:
    """Every registered method that can be loaded in this build and whose required option is in ``given``, and
    those that cannot run."""
    from ..methods import METHODS

    ok, missing = [], []
    for name, spec in METHODS.items():
        if spec.requires and spec.requires not in given:
            missing.append(f"{name} (needs --{spec.requires.replace('_', '-')})")
            continue
        try:
            spec.load()
        except (ImportError, AttributeError):
            missing.append(name)
        else:
            ok.append(name)
    return ok, missing


def _fmt(value) -> str:
    """A number for a table cell: no exponents, three significant digits below 100."""
    if value is None:
        return "\u2013"
    if abs(value) >= 100:
        return f"{value:,.0f}"
    return f"{value:.3g}" if abs(value) >= 0.001 else f"{value:.1e}"


def _show(result, quiet: bool) -> None:
    out = console(quiet)
    data = result.data
    units = data.units
    summary = result.summary()
    settings = result.settings
    gap = ""
    if "occlusion_min_frames" in settings:
        gap = f", occlusions of {settings['occlusion_min_frames']}-{settings['occlusion_max_frames']} frames"
    if settings.get("max_gap_frames") is not None:
        gap += f", fills leave gaps over {settings['max_gap_frames']} frames"
    if settings.get("edges", "fill") != "fill":
        gap += ", fills leave edge gaps"
    out.print(f"[bold]{data.path}[/bold]: {data.n_markers} markers, {data.n_frames} frames at {data.rate:g} Hz; "
              f"protocol {result.protocol}, {len(result.trials)} trials{gap}, seed {result.seed}", highlight=False)
    if settings.get("references"):
        out.print(f"reference takes: {', '.join(settings['references'])}", highlight=False)
        from ..evaluation import reference_words

        for method in result.methods:
            if summary[method].get("references"):
                out.print(f"  {method}: {reference_words(summary[method]['references'])}", highlight=False)
    oracle = " [ORACLE: outlier ranges from the clean file itself]" if settings.get("oracle") else ""

    table = Table(title=f"errors over the hidden samples, in {units} (MSE in {units}\u00b2, Eq. 13){oracle}",
                  title_justify="left")
    table.add_column("method")
    honesty = any(summary[m]["error_ratio"]["median"] is not None for m in result.methods)
    ik = result.ik is not None
    for head in ("RMSE mean", "RMSE median", "max error", "MSE", "bone error", "seconds") + ("err/std",) * honesty:
        table.add_column(head, justify="right")
    if ik:  # joint angles beside the millimetres: medians over trials of the median and worst coordinate
        for head in ("angle med \u00b0", "angle worst \u00b0", f"transl. med {units}", f"transl. worst {units}"):
            table.add_column(head, justify="right")
    from ..evaluation import problem_words

    any_problem = any(problem_words(summary[m]) for m in result.methods)
    if any_problem:
        table.add_column("problems")
    ranking = result.ranking("rmse", "mean")
    best = result.best("rmse", "mean")
    for method in ranking:
        row = summary[method]
        cells = [_fmt(row["rmse"]["mean"]), _fmt(row["rmse"]["median"]), _fmt(row["max_error"]["mean"]),
                 _fmt(row["mse"]["mean"]), _fmt(row["bone_error"]["mean"]), _fmt(row["seconds"]["mean"])]
        if honesty:
            cells.append(_fmt(row["error_ratio"]["median"]))
        if ik:
            cells += [_fmt(row[m]["median"]) for m in ("angle_median", "angle_worst", "translation_median",
                                                         "translation_worst")]
        style = "bold green" if method == best and len(ranking) > 1 else None
        if any_problem:
            cells.append(problem_words(row))
        table.add_row(method, *cells, style=style)
    if ik:
        left = result.left_missing_summary()
        cells = [""] * (6 + honesty) + [_fmt(left[m]["median"]) for m in ("angle_median", "angle_worst",
                                                                          "translation_median", "translation_worst")]
        table.add_row("(left missing)", *cells + [""] * any_problem, style="italic")
    out.print(table)
    if ik:
        out.print(f"joint angles: RMSE over the frames with a hidden sample of OpenSim IK ({result.ik['frames']} frames,"
                  f" {sum(k == 'rotational' for k in result.ik['coordinates'].values())} rotational coordinates) on "
                  "the fill against IK on the complete capture; median over trials of the median and worst "
                  "coordinate. '(left missing)': the hidden markers left out of IK where they are missing.",
                  highlight=False)
    if len(result.methods) > 1:
        rates = result.win_rates("rmse")
        wins = Table(title="win rate by RMSE: row beats column",
                     title_justify="left")
        wins.add_column("")
        for method in ranking:
            wins.add_column(method, justify="right")
        for a in ranking:
            wins.add_row(a, *["" if a == b else ("\u2013" if rates[a][b] is None else f"{100 * rates[a][b]:.0f} %")
                              for b in ranking])
        out.print(wins)
    # one value per trial (every method of a trial shares its rejection)
    detected = [s.detected for s in result.scores[::len(result.methods)] if s.detected is not None]
    if detected:
        out.print(f"outlier rejection caught {100 * sum(detected) / len(detected):.1f} % of the shifted samples "
                  f"(mean over trials; median {100 * float(np.median(detected)):.1f} %, worst trial "
                  f"{100 * min(detected):.1f} %)")
    if settings.get("max_gap_frames") is not None or settings.get("edges", "fill") != "fill":
        costs = []
        for method in ranking:
            mine = [s for s in result.scores if s.method == method and not s.error]
            scored, unfilled = sum(s.n_scored for s in mine), sum(s.unfilled for s in mine)
            costs.append(f"{method} {unfilled} of {scored} ({100 * unfilled / max(scored, 1):.1f} %)")
        out.print("hidden samples left missing by the limits: " + ", ".join(costs), highlight=False)
    errors = sorted({f"{s.method}: {s.error}" for s in result.scores if s.error})
    for message in errors[:10]:
        out.print(f"[yellow]failure[/yellow] {message}", highlight=False)
    if best is None:  # every RMSE is "-": naming the first of them would crown a method that scored nothing
        out.print("best by mean RMSE: none (no method scored any hidden sample)")
    else:
        out.print(f"best by mean RMSE: [bold]{best}[/bold]")
    if ik:
        out.print(angle_headline(result))


def angle_headline(result) -> str:
    """One line: which method is best for joint angles, against leaving the markers missing."""
    best = result.best_for_angles()
    left = result.left_missing_summary()
    lm, lw = left["angle_median"]["median"], left["angle_worst"]["median"]
    if best is None:
        return "best for joint angles: none (IK failed on every fill)"
    row = result.summary()[best]
    med, worst = row["angle_median"]["median"], row["angle_worst"]["median"]
    versus = (f"; leaving the markers missing: {_fmt(lm)}\u00b0 / {_fmt(lw)}\u00b0" if lm is not None else "")
    return (f"best for joint angles: [bold]{best}[/bold] (median coordinate {_fmt(med)}\u00b0, worst coordinate "
            f"{_fmt(worst)}\u00b0, medians over trials{versus})")


def _renamed(ctx: click.Context, param: click.Parameter, value) -> None:
    """``--gap-min`` / ``--gap-max`` were renamed: say so in one line."""
    if value is not None:
        new = param.opts[0].replace("--gap", "--occlusion")
        raise click.ClickException(f"{param.opts[0]} is now {new} (the length of the occlusions evaluate makes; "
                                   "--max-gap limits the fill, as in fill)")


@cli.command("evaluate")
@click.argument("clean_file", type=str)
@click.option("-m", "--methods", multiple=True, metavar="A,B,...",
              help="Methods to compare, comma-separated or the option repeated (default: every available method).")
@click.option("-p", "--protocol", type=click.Choice(PROTOCOL_CHOICES), default="marker", show_default=True,
              help="marker: one marker, one gap; limb: neighbouring markers share a gap; blackout: every marker, "
                   "a short span; random: random gaps and shifted markers (Holden's corruption); dense: random "
                   "gaps until --missing of the samples are gone; segment: a marker and its neighbours within "
                   "--radius vanish together, --events times.")
@click.option("-n", "--trials", type=click.IntRange(min=1), default=10, show_default=True, help="Number of trials.")
@click.option("-s", "--seed", type=int, default=None, help="Seed of the occlusions and of the methods "
                                                          "(default: drawn, and printed so a run can be repeated).")
@click.option("--occlusion-min", default=None, metavar="LEN",
              help="Shortest occlusion the protocol makes: frames (40), seconds (0.5s) or percent of the clip "
                   "(10%). Default per protocol: marker/limb 10% (at most 1s), blackout 0.05s, random 0.05s, dense "
                   "0.25s, segment 0.5s.")
@click.option("--occlusion-max", default=None, metavar="LEN",
              help="Longest occlusion (same forms). Default: marker/limb 50% (at most 5s), blackout 0.25s, random "
                   "0.5s, dense 2s, segment 3s.")
@click.option("--gap-min", "old_gap_min", default=None, hidden=True, expose_value=False, callback=_renamed)
@click.option("--gap-max", "old_gap_max", default=None, hidden=True, expose_value=False, callback=_renamed)
@click.option("--max-gap", "max_gap", default=None, metavar="DURATION",
              help="As fill --max-gap: every fill leaves gaps longer than this (frames or 0.5s) missing, and the "
                   "hidden samples in them count as unfilled (what the limit costs).")
@click.option("--edges", type=click.Choice(["fill", "leave"]), default="fill", show_default=True,
              help="As fill --edges (the protocols hide interior stretches; this changes the clip's own edge gaps).")
@click.option("--limb-size", type=click.IntRange(min=2), default=2, show_default=True,
              help="Markers hidden together by the limb protocol.")
@click.option("--missing", type=click.FloatRange(0, 0.9, min_open=True), default=0.2, show_default=True,
              help="dense protocol: fraction of the observed samples to hide.")
@click.option("--radius", default=None, metavar="LEN",
              help="segment protocol: markers within this median distance of the chosen one vanish with it "
                   "(a number in the file's units, or 250mm, 25cm, 0.25m; default 250 mm).")
@click.option("--events", type=click.IntRange(min=1), default=3, show_default=True,
              help="segment protocol: segments vanishing per trial.")
@click.option("--occlusions", "occlusions", type=str, default=None, metavar="SPEC.json",
              help="Replay exactly the trials of this spec file (see docs/occlusions.md) instead of drawing them; "
                   "the --json output of an earlier run works too.")
@click.option("--save-occlusions", type=str, default=None, metavar="SPEC.json",
              help="Write the trials of this run as a spec file for --occlusions.")
@click.option("-j", "--jobs", type=click.IntRange(min=0), default=1, show_default=True,
              help="Trials run in parallel in this many processes (0 = every CPU); the numbers do not change.")
@click.option("-o", "--option", "option_pairs", multiple=True, metavar="KEY=VALUE",
              help="A fill option for every method that takes it (repeatable), e.g. -o max_iter=50 -o hidden=12.")
@click.option("--reject-outliers", type=click.Choice(["self", "clean"]), default=None,
              help="Run outlier rejection on each corrupted clip before filling (for the random protocol): "
                   "'self' uses the corrupted clip as its own reference (as fill does), 'clean' uses the clean "
                   "file as Holden's reference take (an oracle: it has seen the truth; tables say so).")
@click.option("--reference", "references", type=str, multiple=True,
              help="A reference take of the same marker set (repeatable; never the clean file itself) for the "
                   "methods that train on references (auto, pca).")
@click.option("--ik", "ik_setup", type=str, default=None, metavar="SETUP.xml",
              help="Also score joint angles: OpenSim inverse kinematics with this IK setup on each fill, on the "
                   "capture with the hidden markers left missing, and on the complete capture (needs the extra "
                   "mocapfill[opensim]).")
@click.option("--ik-model", type=str, default=None, metavar="MODEL.osim",
              help="The scaled OpenSim model for --ik (where the setup names none or another) and for the "
                   "opensim-ik method.")
@click.option("--report", "report_path", type=str, default=None, metavar="PATH.html|PATH.json",
              help="Write the evaluation as a self-contained HTML page or as JSON (by extension).")
@click.option("--json", "as_json", is_flag=True, help="Print every trial as JSON on stdout.")
@click.option("--csv", "as_csv", is_flag=True, help="Print every trial as CSV on stdout.")
@input_options
@quiet_option
def evaluate(clean_file: str, methods: tuple[str, ...], protocol: str, trials: int, seed: int | None,
             occlusion_min: str | None, occlusion_max: str | None, max_gap: str | None, edges: str,
             limb_size: int, missing: float, radius: str | None,
             events: int, occlusions: str | None,
             save_occlusions: str | None, jobs: int, option_pairs: tuple[str, ...], reject_outliers: str | None,
             references: tuple[str, ...], ik_setup: str | None, ik_model: str | None, report_path: str | None,
             as_json: bool, as_csv: bool, reading: ReadOptions, quiet: bool) -> None:
    """Score fill methods on CLEAN_FILE: hide samples it has, fill them with each method, compare with the truth.

    Metrics per trial and method, over the hidden samples, in the file's units: RMSE and max error of the 3-D
    position, the BoLeRO paper's MSE (Eq. 13, per coordinate), the mean absolute bone-length error on the hidden
    frames (bones estimated from the occluded input), seconds, and for methods that say how sure they are, the RMS
    error per coordinate over the RMS of their predicted std ("err/std": 1 = honest, 2 = twice as wrong as
    they said).  The table on stderr gives the mean and median per method (err/std: the median) and how often
    each method beats each other one.  With --ik SETUP.xml, also the joint-angle errors (degrees) of OpenSim IK.
    """
    from ..evaluation import evaluate as run_evaluation
    from ..methods import get_method

    if as_json and as_csv:
        raise click.UsageError("choose one of --json and --csv")
    options = _parse_options(option_pairs)
    out = console(quiet)
    if report_path is not None and not report_path.lower().endswith((".html", ".htm", ".json")):
        raise click.BadParameter("the report's name must end in .html or .json", param_hint="'--report'")
    given = ({"ik_model"} if (ik_model or ik_setup) else set()) | set(options)  # -o model=F: the learned method
    if not methods:
        names, unavailable = _default_methods(given)
        if unavailable:
            out.print(f"not available in this build, skipped: {', '.join(unavailable)}", highlight=False)
    else:
        names = list(dict.fromkeys(m.strip() for given_text in methods for m in given_text.split(",") if m.strip()))
        if not names:
            raise click.BadParameter("give at least one method", param_hint="'--methods'")
        for name in names:
            spec = get_method(name)  # unknown names fail here, before the file is read
            if spec.requires and spec.requires not in given:
                needs = "--ik-model MODEL.osim" if spec.requires == "ik_model" else f"-o {spec.requires}=FILE"
                raise MethodError(f"method {name!r} needs {needs}")
    _check_option_types(option_pairs, options, names)
    if ik_setup or any(get_method(n).requires == "ik_model" for n in names):
        from ..kinematics.opensim_ik import require_opensim

        require_opensim()  # one line naming the extra, before the file is read
    data = read_input(clean_file, reading, quiet=quiet)
    from ..methods.base import check_frames

    check_frames(data.n_frames, name=clean_file)  # else a header only reads as "every sample is missing"
    if data.missing.all():
        raise MocapfillError(f"{clean_file}: every sample is missing; nothing to hide")
    protocol_options = {}
    if not occlusions:
        protocol_options = {"limb": {"limb_size": limb_size}, "dense": {"missing": missing},
                            "segment": {"radius": parse_length(radius, data.units, "--radius"),
                                        "events": events}}.get(protocol, {})

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    with Progress(TextColumn("evaluating"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=out, transient=True, disable=quiet) as bar:
        task = bar.add_task("trials", total=None)

        def progress(done: int, total: int) -> None:
            bar.update(task, completed=done, total=total)

        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", UserWarning)
            result = run_evaluation(data, names, protocol, trials=trials, seed=seed, occlusions=occlusions,
                                    occlusion_min=occlusion_min, occlusion_max=occlusion_max, max_gap=max_gap,
                                    edges=edges, jobs=jobs, options=options,
                                    reject_outliers=reject_outliers, progress=progress,
                                    save_occlusions=save_occlusions, ik=ik_setup, ik_model=ik_model,
                                    reference=[read_input(path, reading._replace(format=None, override_rate=True),
                                                          quiet=quiet) for path in references] or None,
                                    **protocol_options)
    show_warnings(caught, quiet)
    if save_occlusions:
        out.print(f"occlusions written to {save_occlusions}", highlight=False)
    _show(result, quiet)
    if report_path is not None:
        from ..report.evaluation_html import write_evaluation_report

        write_evaluation_report(result, report_path)
        out.print(f"report written to {report_path}", highlight=False)
    if as_json:
        sys.stdout.write(json.dumps(result.to_dict(), indent=1, allow_nan=False) + "\n")
    elif as_csv:
        sys.stdout.write(result.to_csv())
    sys.stdout.flush()
    summary = result.summary()
    if all(summary[m]["failures"] == len(result.trials) for m in result.methods):
        # every method failed every trial (the failures are listed above): nothing was evaluated
        raise click.ClickException(f"{clean_file}: every method failed on every trial; nothing was scored")
