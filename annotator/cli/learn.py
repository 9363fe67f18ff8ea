"""``annotator learn train``: the small learner of the labels (docs/learning.md)."""

from __future__ import annotations

import logging
import time
from pathlib import Path

import click

from annotator.cli.common import (
    CONTEXT,
    VERBOSE_OPTION,
    file_option,
    folder_option,
    overwrite_option,
    setup_logging,
)


@click.group("learn", context_settings=CONTEXT)
def learn_group() -> None:
    """Train a grasp classifier on scene labels and use it as a clutter-removal policy.

    \b
    annotate --objects objects/ --scenes 100 --n 120 --views 3 --out scene_labels/
    annotator learn train scene_labels/ --objects objects/ --out model.npz
    annotator clutter-removal --objects others/ --rounds 20 --policy learned --policy-arg model=model.npz
    """


@learn_group.command("train", context_settings=CONTEXT)
@click.argument(
    "labels", nargs=-1, required=True, type=click.Path(path_type=Path, exists=True, file_okay=False)
)
@file_option(
    "--out",
    "out",
    required=True,
    help="The model (.npz).",
)
@click.option(
    "--holdout",
    type=click.FloatRange(0.0, 0.9),
    default=0.2,
    show_default=True,
    help="Share of the scenes (the last by id) kept out to report the model's AUC, then trained on too.",
)
@folder_option(
    "--objects",
    "objects",
    exists=True,
    default=None,
    help="The folder the labels were made from: adds the policy's own candidates in each scene, "
    "tried in simulation (recommended; without it the model learns mostly to tell collisions).",
)
@overwrite_option("Replace an --out file this tool did not write, or one changed since.")
@VERBOSE_OPTION
def train_command(labels, out, holdout, objects, overwrite, verbose):
    """Train on the labels of annotate --scenes ... --views K runs (LABELS: their folders).

    Each labelled grasp is described by the observed cloud around it in the gripper's frame (the
    scene's depth views, as a policy sees them) and a logistic regression learns which hold. With
    --objects each scene also adds the vision candidates the policy will score, each tried in
    simulation. Prints the held-out scenes' AUC and writes the model.
    """
    setup_logging(False, verbose, default=logging.WARNING)
    import numpy as np

    from annotator.learn.data import MeshMismatchError, load_training_set
    from annotator.learn.model import auc, train
    from annotator.tools.common import ToolError, claim_outputs

    claimed = claim_outputs("annotator learn train", {"--out": out}, overwrite)
    t0, c0 = time.perf_counter(), time.process_time()
    try:
        data = load_training_set(list(labels), objects)
    except MeshMismatchError as exc:
        raise ToolError(str(exc)) from None
    except (OSError, ValueError, KeyError) as exc:
        raise ToolError(f"the labels cannot be read for learning: {exc}") from None
    scenes = np.unique(data.scene_id)
    held_out = scenes[len(scenes) - int(round(holdout * len(scenes))) :] if holdout > 0 else scenes[:0]
    test = np.isin(data.scene_id, held_out)
    if holdout > 0 and not (test.any() and (~test).any()):
        kept = "every scene" if test.all() else "no scene"
        click.echo(
            f"no held-out figure: --holdout {holdout:g} of {len(scenes)} scenes keeps {kept} out; "
            "give more scenes or another --holdout"
        )
    click.echo(
        f"{len(data.y)} grasps of {len(scenes)} scenes ({int(data.vision.sum())} vision candidates), "
        f"{int(data.y.sum())} held; "
        f"{len(data.X[0])} features each ({time.perf_counter() - t0:.0f} s to read)"
    )
    try:
        if test.any() and (~test).any():
            model = train(data.X[~test], data.y[~test])
            p = model.probability(data.X[test])
            accuracy = float(((p > 0.5) == data.y[test]).mean())
            click.echo(
                f"held-out {len(held_out)} scenes ({int(test.sum())} grasps): "
                f"AUC {auc(p, data.y[test]):.3f}, "
                f"accuracy at 0.5 {100 * accuracy:.1f} % (balanced classes in training)"
            )
            vision = data.vision[test]
            if vision.any():
                held_out_auc = auc(p[vision], data.y[test][vision])
                click.echo(f"  on their vision candidates ({int(vision.sum())}): AUC {held_out_auc:.3f}")
        model = train(data.X, data.y)
    except ValueError as exc:
        raise ToolError(str(exc)) from None
    written = claimed.write("--out", model.save)
    click.echo(
        f"wrote {written} ({time.perf_counter() - t0:.0f} s, "
        f"{time.process_time() - c0:.0f} CPU-s of this process)"
    )
