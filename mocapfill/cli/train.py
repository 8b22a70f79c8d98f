"""`mocapfill train CLEAN_TAKES... --output layout.model`: learn a denoiser for one marker layout (Holden 2018).

A thin door over :func:`mocapfill.engines.denoiser_training.train` (needs the ``learn`` extra: JAX and optax).  The
takes are matched by label to the first one (a ``Subject:`` prefix aside; the markers every take carries form the
layout) and converted to its units; their complete frames train the network.  Progress on stderr.
"""

from __future__ import annotations

import warnings

import click
import numpy as np

from ..errors import MocapfillError
from . import cli
from .common import (ReadOptions, StderrProgress, console, input_options, quiet_option, read_input,
                     show_warnings)


class _TrainBar(StderrProgress):
    def __init__(self, quiet: bool) -> None:
        def columns():
            from rich.progress import BarColumn, MofNCompleteColumn, TextColumn, TimeElapsedColumn

            return (TextColumn("training"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("loss {task.fields[loss]}"), TimeElapsedColumn())

        super().__init__(quiet, columns, loss="-")

    def __call__(self, step: int, steps: int, loss: float) -> None:
        self.update(completed=step, total=steps, loss=f"{loss:.4f}")


@cli.command("train")
@click.argument("takes", metavar="CLEAN_TAKES...", nargs=-1, required=True, type=str)
@click.option("-o", "--output", "output_path", required=True, type=str,
              help="Model file to write (e.g. layout.model).")
@click.option("--steps", type=click.IntRange(min=1), default=None, help="Training steps (default 3000).")
@click.option("--hidden", type=click.IntRange(min=4), default=None, help="Hidden units per layer (default 256).")
@click.option("--blocks", type=click.IntRange(min=0), default=None, help="Residual blocks (default 2).")
@click.option("--batch", "batch_size", type=click.IntRange(min=8), default=None, help="Mini-batch (default 256).")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the weights and the corruption.")
@input_options
@quiet_option
def train_command(takes: tuple[str, ...], output_path: str, steps, hidden, blocks, batch_size, seed: int,
                  reading: ReadOptions, quiet: bool) -> None:
    """Train a denoiser on CLEAN_TAKES of one marker layout and write it to --output.

    Each mini-batch is corrupted on the fly as Holden (2018) does (markers occluded, displaced by up to 50 cm, swapped
    with a neighbour; noise), in a body frame fitted to the torso markers; the network learns the clean positions.
    Use it with `mocapfill fill IN OUT --method learned --model FILE` (and `--denoise`).
    """
    from ..engines.denoiser import save_model
    from ..engines.denoiser_training import require_jax, train
    from ..io.atomic import check_output_path
    from ..references import bare_label, match_reference

    require_jax()  # fail in one line before reading anything
    check_output_path(output_path, *takes)
    datas = [read_input(path, reading, quiet=quiet) for path in takes]
    first = datas[0]
    keep = [k for k, kind in enumerate(first.kinds or ["marker"] * first.n_markers) if kind == "marker"]
    labels = [bare_label(first.labels[k]) for k in keep]

    def nothing_observed(path: str) -> MocapfillError:
        return MocapfillError(f"{path}: nothing observed to train on (every sample of the layout's markers is "
                              "missing)")

    for d, path in zip(datas, takes):
        if np.isnan(d.positions).all():  # said before the markers it lacks, which would be all of them
            raise nothing_observed(path)
    with warnings.catch_warnings(record=True) as caught:  # (each a one-line warning, as the other commands give)
        warnings.simplefilter("always")
        matched = [match_reference(labels, first.units, d.positions, list(d.labels), d.units, name=path)
                   for d, path in zip(datas, takes)]
    show_warnings(caught, quiet)
    for m, path in zip(matched, takes):
        if np.isnan(m.positions).all():  # one line naming the take, not a reduction over no markers downstream
            raise nothing_observed(path)
    shared = np.all([~np.isnan(m.positions).any(axis=2).all(axis=0) for m in matched], axis=0)
    if not shared.any():
        raise MocapfillError(f"{', '.join(takes)}: no marker is observed in every take; nothing to train on")
    layout = [label for label, ok in zip(labels, shared) if ok]
    arrays = [m.positions[:, shared] for m in matched]
    options = {k: v for k, v in (("steps", steps), ("hidden", hidden), ("blocks", blocks), ("batch", batch_size))
               if v is not None}
    with _TrainBar(quiet) as bar:
        model = train(arrays, layout, first.units, seed=seed, names=list(takes),
                      progress=bar if bar.enabled else None, **options)
    save_model(model, output_path)
    s = model.settings
    console(quiet).print(f"trained on {s['frames']} frames of {len(takes)} take(s), {len(layout)} markers, "
                         f"{model.n_parameters()} parameters, {s['steps']} steps in {s['seconds']:.1f} s; "
                         f"validation loss {s['validation_loss']:.3f}; wrote {output_path}", highlight=False,
                         soft_wrap=True)
