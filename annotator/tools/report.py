"""A dataset at a glance: one self-contained HTML file (no network, pictures embedded as data URIs).

Sections: the run (configuration and versions from ``_manifest.json``), objects that failed with
their reasons, per-object success rates and outcome mix with mass and collision error, width and
score histograms, the distribution of approach directions, and ``show`` pictures of a few objects.
Charts are inline SVG written here (no plotting dependency); the page has no script but a check
that every embedded picture decoded (it logs a console error otherwise).
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from annotator.dataset import OUTCOMES, poses_as_matrices
from annotator.outcome import OUTCOME_RGB

log = logging.getLogger(__name__)

# Keys of the run's per-object record (the manifest's objects_info.<id>.geometry) for the per-object
# table: mass (kg) and the mean distance (m) between the collision shape and the mesh surface.
MASS_COLUMNS = ("mass",)
COLLISION_ERROR_COLUMNS = ("collision_error_mean",)
# each outcome's colour as the pictures draw it (annotator.outcome.OUTCOME_RGB), in hex
OUTCOME_HEX = {o: "#" + "".join(f"{c:02x}" for c in rgb) for o, rgb in OUTCOME_RGB.items()}
NA = '<span class="na">n/a</span>'

CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",Roboto,sans-serif;margin:24px auto;max-width:1100px;
color:#222;padding:0 16px}
h1{font-size:1.6em;margin-bottom:4px}h2{margin-top:32px;border-bottom:1px solid #ddd;padding-bottom:4px}
table{border-collapse:collapse;font-size:0.9em;margin:8px 0}
td,th{border:1px solid #ddd;padding:3px 6px;text-align:right}th{background:#f5f5f5}
td.l,th.l{text-align:left}.na{color:#999}.muted{color:#666;font-size:0.9em}
.grid{display:flex;flex-wrap:wrap;gap:16px}.card{flex:1 1 480px}
img{max-width:100%;border:1px solid #eee}details{margin:6px 0}code{background:#f5f5f5;padding:1px 4px}
.sw{display:inline-block;width:10px;height:10px;margin:0 3px 0 10px}
.unfinished{background:#fff3cd;border:1px solid #e6c200;padding:6px 10px}
"""

# Flags every embedded picture that did not decode (a console error the report's test looks for).
IMAGE_CHECK = """
window.addEventListener('load', function () {
  var bad = Array.prototype.filter.call(document.images, function (im) {
    return !im.complete || im.naturalWidth === 0;
  });
  if (bad.length) { console.error('report: ' + bad.length + ' picture(s) did not decode'); }
});
"""


@dataclass(frozen=True)
class ReportResult:
    """What ``report`` wrote: the page, its counts, and the state of the labels' run."""

    path: Path
    n_objects: int
    n_grasps: int
    pictures: int
    run_state: str = "finished"  # or why the labels' run is unfinished


# ------------------------------------------------------------------------------------ helpers


def _e(text: object) -> str:
    return html.escape(str(text))


def _png_uri(image: np.ndarray | Path) -> str:
    from PIL import Image

    if isinstance(image, Path):
        data = image.read_bytes()
    else:
        buf = io.BytesIO()
        Image.fromarray(image).save(buf, format="PNG", optimize=True)
        data = buf.getvalue()
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def _svg(width: int, height: int, body: str, label: str) -> str:
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" role="img" aria-label="{_e(label)}">{body}</svg>'
    )


def _text(x: float, y: float, text: object, anchor: str = "start", size: int = 10) -> str:
    return f'<text x="{x:.1f}" y="{y:.1f}" font-size="{size}" text-anchor="{anchor}">{_e(text)}</text>'


def histogram_svg(
    series: dict[str, np.ndarray],
    colors: dict[str, str],
    bins: np.ndarray,
    xlabel: str,
    scale: float = 1.0,
    width: int = 480,
    height: int = 220,
) -> str:
    """Stacked histogram of several series over ``bins`` as SVG; x tick labels are ``value x scale``."""
    left, right, top, bottom = 44, 10, 22, 36
    pw, ph = width - left - right, height - top - bottom
    counts = {k: np.histogram(np.clip(v, bins[0], bins[-1]), bins)[0] for k, v in series.items()}
    total = np.sum([c for c in counts.values()], axis=0) if counts else np.zeros(len(bins) - 1)
    peak = max(int(total.max()) if len(total) else 0, 1)
    bw = pw / (len(bins) - 1)
    parts = [f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="#fafafa" stroke="#ccc"/>']
    base = np.zeros(len(bins) - 1)
    for name, c in counts.items():
        for i, n in enumerate(c):
            if n:
                h = ph * n / peak
                y = top + ph - ph * base[i] / peak - h
                fill = colors.get(name, "#555")
                parts.append(
                    f'<rect x="{left + i * bw + 0.5:.1f}" y="{y:.1f}" width="{max(bw - 1, 0.5):.1f}" '
                    f'height="{h:.1f}" fill="{fill}"><title>{_e(name)}: {n}</title></rect>'
                )
        base = base + c
    for frac in (0.0, 0.5, 1.0):
        y = top + ph - ph * frac
        parts.append(_text(left - 4, y + 4, round(peak * frac), "end"))
    for i in range(0, len(bins), max(1, (len(bins) - 1) // 5)):
        x = left + i * bw
        parts.append(_text(x, top + ph + 14, f"{bins[i] * scale:.3g}", "middle"))
    parts.append(
        f'<text x="{left + pw / 2}" y="{height - 6}" font-size="11" text-anchor="middle">{_e(xlabel)}</text>'
    )
    x = left
    for name in counts:
        parts.append(f'<rect x="{x}" y="6" width="10" height="10" fill="{colors.get(name, "#555")}"/>')
        parts.append(f'<text x="{x + 13}" y="15" font-size="10">{_e(name)}</text>')
        x += 20 + 6 * len(name)
    return _svg(width, height, "".join(parts), f"histogram of {xlabel}")


def outcome_bar_svg(counts: dict[str, int], width: int = 120, height: int = 14) -> str:
    """One stacked bar of an object's outcome mix (hover for counts)."""
    total = max(sum(counts.values()), 1)
    x, parts = 0.0, []
    for outcome in OUTCOMES:
        n = counts.get(outcome, 0)
        if n:
            w = width * n / total
            parts.append(
                f'<rect x="{x:.1f}" y="0" width="{w:.1f}" height="{height}" fill="{OUTCOME_HEX[outcome]}">'
                f"<title>{outcome}: {n}</title></rect>"
            )
            x += w
    return _svg(width, height, "".join(parts), "outcome mix")


def approach_directions(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Azimuth (deg, -180..180) and elevation (deg, -90..90) of each grasp's approach (TCP +z)
    in the object's mesh frame; elevation -90 is a grasp from above (approaching downwards)."""
    z = poses_as_matrices(df)[:, :3, 2]
    azimuth = np.degrees(np.arctan2(z[:, 1], z[:, 0]))
    elevation = np.degrees(np.arcsin(np.clip(z[:, 2], -1.0, 1.0)))
    return azimuth, elevation


def approach_map_svg(df: pd.DataFrame, n_az: int = 24, n_el: int = 12, cell: int = 16) -> str:
    """Equal-area map of approach directions: cell shade = grasps, green ring share = success rate.

    Rows are bands of equal sin(elevation), so every cell covers the same solid angle.
    """
    az, el = approach_directions(df)
    ok = df["success"].to_numpy(dtype=bool)
    ai = np.clip(((az + 180.0) / 360.0 * n_az).astype(int), 0, n_az - 1)
    ei = np.clip(((np.sin(np.radians(el)) + 1.0) / 2.0 * n_el).astype(int), 0, n_el - 1)
    count = np.zeros((n_el, n_az), int)
    good = np.zeros((n_el, n_az), int)
    np.add.at(count, (ei, ai), 1)
    np.add.at(good, (ei, ai), ok.astype(int))
    left, top = 46, 8
    width, height = left + n_az * cell + 150, top + n_el * cell + 34
    parts = []
    peak = max(int(count.max()), 1)
    for r in range(n_el):
        for c in range(n_az):
            n = count[r, c]
            y = top + (n_el - 1 - r) * cell  # elevation up
            shade = 255 - int(200 * n / peak)
            fill = f"rgb({shade},{shade},{shade})" if n else "#fff"
            rate = good[r, c] / n if n else 0.0
            tip = f"{n} grasps, {good[r, c]} held" if n else "no grasps"
            parts.append(
                f'<rect x="{left + c * cell}" y="{y}" width="{cell}" height="{cell}" fill="{fill}" '
                f'stroke="#eee"><title>{tip}</title></rect>'
            )
            if good[r, c]:
                rad = 0.45 * cell * np.sqrt(rate)
                parts.append(
                    f'<circle cx="{left + c * cell + cell / 2}" cy="{y + cell / 2}" r="{rad:.1f}" '
                    f'fill="{OUTCOME_HEX["success"]}"><title>{tip}</title></circle>'
                )
    for deg in (-90, -30, 0, 30, 90):
        y = top + n_el * cell * (1 - (np.sin(np.radians(deg)) + 1) / 2)
        parts.append(f'<text x="{left - 4}" y="{y + 4:.1f}" font-size="10" text-anchor="end">{deg}°</text>')
    for deg in (-180, -90, 0, 90, 180):
        x = left + n_az * cell * (deg + 180) / 360
        parts.append(_text(x, top + n_el * cell + 13, f"{deg}°", "middle"))
    parts.append(
        f'<text x="{left + n_az * cell / 2}" y="{height - 4}" font-size="11" text-anchor="middle">'
        "azimuth of the approach (object frame)</text>"
    )
    lx = left + n_az * cell + 12
    parts.append(f'<text x="{lx}" y="{top + 12}" font-size="10">grey: grasps ({peak} max)</text>')
    parts.append(f'<text x="{lx}" y="{top + 28}" font-size="10">green disc: success rate</text>')
    parts.append(f'<text x="{lx}" y="{top + 44}" font-size="10">up: approach upwards</text>')
    parts.append(f'<text x="{lx}" y="{top + 60}" font-size="10">(-90°: from above)</text>')
    return _svg(width, height, "".join(parts), "approach directions")


def _recorded(manifest: dict | None, object_id: str, names: tuple[str, ...]) -> float:
    """A number the run recorded about an object as simulated (its geometry record in the
    manifest, ``objects_info.<id>.geometry``, or ``objects_info.<id>``), NaN if none."""
    entry = ((manifest or {}).get("objects_info") or {}).get(object_id) or {}
    for where in (entry.get("geometry"), entry):
        if isinstance(where, dict):
            value = next((where[k] for k in names if isinstance(where.get(k), int | float)), None)
            if value is not None:
                return float(value)
    return float("nan")


def per_object_table(df: pd.DataFrame, manifest: dict | None = None) -> pd.DataFrame:
    """One row per object: n, successes, rate, outcome counts, mass (kg), collision error (or NaN).

    Mass and collision error (mean distance of the collision shape from the mesh) come from what
    the run recorded per object (the manifest's geometry record), else from the labels' own
    columns (``object_mass``, ``collision_error_mean``); ``NaN`` (shown n/a) when none has them.
    """
    counts = df.groupby("object_id")["outcome"].value_counts().unstack(fill_value=0)
    table = pd.DataFrame(index=counts.index)
    table["n"] = counts.sum(axis=1)
    table["successes"] = counts.get("success", 0)
    table["rate"] = table["successes"] / table["n"]
    for outcome in OUTCOMES:
        table[outcome] = counts.get(outcome, 0)
    for name, recorded, column in (
        ("mass", MASS_COLUMNS, "object_mass"),
        ("collision_error", COLLISION_ERROR_COLUMNS, "collision_error_mean"),
    ):
        values = pd.Series([_recorded(manifest, oid, recorded) for oid in table.index], index=table.index)
        if column in df.columns and pd.api.types.is_numeric_dtype(df[column]):
            values = values.fillna(df.groupby("object_id")[column].median())
        table[name] = values
    return table


# ------------------------------------------------------------------------------------ sections


def _run_section(manifest: dict | None, gripper_line: str = "") -> str:
    if manifest is None:
        return (
            "<p class='muted'>No <code>_manifest.json</code> beside the labels: run settings unknown.</p>"
            + (f"<p>{_e(gripper_line)}</p>" if gripper_line else "")
        )
    from annotator.tools.common import run_settings

    run = run_settings(manifest)
    rows = [
        ("gripper", gripper_line.removeprefix("gripper: ")),
        ("seed", run.get("seed")),
        ("candidates per object (n)", run.get("n")),
        ("trials per candidate", run.get("trials")),
        ("scale", run.get("scale") or 1.0),
        ("started", manifest.get("created")),
        ("last update", manifest.get("updated")),
        (
            "objects done / failed",
            f"{len(manifest.get('objects_done', {}))} / {len(manifest.get('objects_failed', {}))}",
        ),
    ]
    out = ["<table>"] + [f"<tr><th class='l'>{_e(k)}</th><td class='l'>{_e(v)}</td></tr>" for k, v in rows]
    out.append("</table><h3>Versions</h3><table>")
    out += [
        f"<tr><th class='l'>{_e(k)}</th><td class='l'>{_e(v)}</td></tr>"
        for k, v in manifest.get("versions", {}).items()
    ]
    out.append("</table><h3>Configuration</h3>")
    for section, values in sorted(run.get("config", {}).items()):
        out.append(f"<details><summary><code>[{_e(section)}]</code></summary><table>")
        if isinstance(values, dict):
            out += [
                f"<tr><th class='l'>{_e(k)}</th><td class='l'>{_e(v)}</td></tr>" for k, v in values.items()
            ]
        out.append("</table></details>")
    return "".join(out)


def _failures_section(manifest: dict | None, df: pd.DataFrame) -> str:
    failed = (manifest or {}).get("objects_failed", {})
    out = []
    if failed:
        out.append("<table><tr><th class='l'>object</th><th class='l'>reason</th></tr>")
        out += [
            f"<tr><td class='l'>{_e(k)}</td><td class='l'>{_e(v)}</td></tr>"
            for k, v in sorted(failed.items())
        ]
        out.append("</table>")
    else:
        out.append("<p>No object failed.</p>")
    errors = df[df["outcome"] == "error"]
    if len(errors):
        per = errors.groupby("object_id").size()
        out.append(
            f"<p>{len(errors)} grasp(s) ended in a simulation <b>error</b> (their object's other grasps are "
            "labelled): " + ", ".join(f"{_e(k)} {v}" for k, v in per.items()) + "</p>"
        )
    return "".join(out)


def _objects_section(table: pd.DataFrame) -> str:
    head = (
        "<div style='overflow-x:auto'><table><tr><th class='l'>object</th><th>n</th>"
        "<th>success rate</th><th class='l'>outcome mix</th>"
        + "".join(f"<th>{o.replace('_', ' ')}</th>" for o in OUTCOMES)
        + "<th>mass (g)</th><th>collision error (mm)</th></tr>"
    )
    rows = []
    for oid, r in table.iterrows():
        counts = {o: int(r[o]) for o in OUTCOMES}
        mass = NA if not np.isfinite(r["mass"]) else f"{1000 * r['mass']:.0f}"
        err = NA if not np.isfinite(r["collision_error"]) else f"{1000 * r['collision_error']:.2f}"
        rows.append(
            f"<tr><td class='l'>{_e(oid)}</td><td>{int(r['n'])}</td><td>{r['rate']:.1%}</td>"
            f"<td class='l'>{outcome_bar_svg(counts)}</td>"
            + "".join(f"<td>{counts[o]}</td>" for o in OUTCOMES)
            + f"<td>{mass}</td><td>{err}</td></tr>"
        )
    legend = "".join(f"<span class='sw' style='background:{OUTCOME_HEX[o]}'></span>{o}" for o in OUTCOMES)
    return head + "".join(rows) + f"</table></div><p class='muted'>{legend}</p>"


def _histograms_section(df: pd.DataFrame, max_width: float | None) -> str:
    ok = df["success"].to_numpy(dtype=bool)
    simulated = df["outcome"].to_numpy() != "collision"
    top = max_width or max(float(df["width"].max()), 0.01)
    width_bins = np.linspace(0.0, top, 23)
    widths = histogram_svg(
        {
            "success": df["width"].to_numpy()[ok],
            "failure (simulated)": df["width"].to_numpy()[~ok & simulated],
        },
        {"success": OUTCOME_HEX["success"], "failure (simulated)": OUTCOME_HEX["slipped_shake"]},
        width_bins,
        "width at the end of closing (mm)",
        scale=1000.0,
    )
    scores = histogram_svg(
        {"score": df["score"].to_numpy()},
        {"score": "#0072b2"},
        np.linspace(0.0, 1.0, 11),
        "score (fraction of trials held)",
    )
    return (
        f"<div class='grid'><div class='card'>{widths}<p class='muted'>Collisions are left out: their "
        f"width is the open width, never simulated.</p></div><div class='card'>{scores}</div></div>"
    )


def _pictures_section(
    labels_dir: Path,
    df: pd.DataFrame,
    objects_dir: Path | None,
    n_objects: int,
    n_grasps: int,
    seed: int,
    gripper=None,
) -> tuple[str, int]:
    """``show`` pictures of the objects with the most successes (ties: object id), drawn with
    ``gripper`` (a description; default the RG2)."""
    from annotator.tools.common import ToolError, object_mesh
    from annotator.tools.show import GraspRenderer, choose_grasps, grasp_sheet, overview

    per = df.groupby("object_id")["success"].sum().sort_values(ascending=False, kind="stable")
    chosen = list(per.index[:n_objects])
    out, n_pictures = [], 0
    for oid in chosen:
        rows = df[df["object_id"] == oid].reset_index(drop=True)
        try:
            mesh = object_mesh(labels_dir, oid, objects_dir, rows)
        except ToolError as exc:
            out.append(f"<p class='muted'>{_e(oid)}: no pictures ({_e(exc.message)})</p>")
            continue
        outcomes = ("success",) if rows["success"].any() else ()
        picked = choose_grasps(rows, n_grasps, seed, outcomes)
        with GraspRenderer(mesh, description=gripper) as renderer:
            sheet = grasp_sheet(renderer, picked)
            ov = overview(renderer, rows)
        counts = rows["outcome"].value_counts().to_dict()
        ov_img = ov.picture(f"{oid}: {len(rows)} grasps by outcome (faint: behind the object)", counts)
        what = "successes" if outcomes else "grasps"
        out.append(
            f"<h3>{_e(oid)}</h3><img alt='{_e(oid)} overview' src='{_png_uri(ov_img)}'>"
            f"<p class='muted'>{len(picked)} of its {what}, front and side views:</p>"
            f"<img alt='{_e(oid)} grasps' src='{_png_uri(sheet)}'>"
        )
        n_pictures += 2
    return "".join(out), n_pictures


# ------------------------------------------------------------------------------------ the report


# Near the page's top: says which program made it (whether a file may be replaced is its mark's
# business: annotator.store.outputs).
GENERATOR = '<meta name="generator" content="rg2-annotator report">'


def _confidence_section(manifest: dict | None, df: pd.DataFrame) -> str:
    """The label's confidence ([confidence], annotator calibrate): the mapping's reliability
    diagram and Brier score on the real trials it was fitted on, and the labels' p_success."""
    from annotator import confidence as conf
    from annotator.tools.common import run_settings

    section = (run_settings(manifest).get("config") or {}).get("confidence") or {}
    if section.get("method", "none") == "none" or "p_success" not in df.columns:
        return (
            "<p class='muted'>No calibration: these labels carry no p_success (annotator calibrate "
            "fits one on real trials; annotate --config with its file adds the column).</p>"
        )
    pairs = zip(section.get("scores", ()), section.get("p_success", ()), strict=False)
    knots = ", ".join(f"{s:.2f}&rarr;{p:.2f}" for s, p in pairs)
    p = df["p_success"].to_numpy(dtype=float)
    mean = (
        f"The labels' mean p_success is {np.nanmean(p):.3f}: the share of them a real robot is "
        "expected to hold."
    )
    if int(section.get("n", 0)) == 0:  # written by hand: nothing measured to show
        return (
            f"<p>p_success maps the score of --trials {int(section.get('trials', 0))} to the probability "
            f"that the real grasp holds by a mapping written by hand (score {knots}): it records no real "
            f"trials, so there is no Brier score and no reliability diagram. {mean}</p>"
        )
    bins = [
        conf.ReliabilityBin(float("nan"), float("nan"), int(k), float(p), float(r))
        for p, r, k in zip(
            section.get("reliability_p", ()),
            section.get("reliability_rate", ()),
            section.get("reliability_n", ()),
            strict=False,
        )
    ]
    brier = float(section.get("brier", float("nan")))
    png = conf.reliability_png([("p_success", bins)], f"Brier {brier:.3f}, cross-validated by object")
    return (
        f"<p>p_success maps the score of --trials {int(section.get('trials', 0))} to the probability "
        f"that the real grasp holds (isotonic over {int(section.get('n', 0))} real trials; score "
        f"{knots}). Brier score {brier:.3f}, cross-validated by object. {mean}</p>"
        f"<img alt='reliability diagram' src='data:image/png;base64,{base64.b64encode(png).decode('ascii')}'>"
    )


def report(
    labels_dir: Path,
    out: Path,
    objects_dir: Path | None = None,
    picture_objects: int = 3,
    picture_grasps: int = 4,
    seed: int = 0,
    gripper=None,
    overwrite: bool = False,
) -> ReportResult:
    """Write the HTML report of the labels in ``labels_dir`` to ``out``.

    ``picture_objects``: how many objects get ``show`` pictures (those with the most successes);
    0 for none. Pictures need the meshes: ``objects_dir`` or the geometry the labels carry.
    ``gripper``: a name, folder or description to draw (default: the one recorded with the labels).
    ``overwrite``: replace an ``out`` this tool did not write (else ToolError before any work).
    """
    from annotator.tools.common import claim_outputs

    with claim_outputs("annotator report", {"--html": out}, overwrite) as claimed:
        return _write_report(claimed, labels_dir, objects_dir, picture_objects, picture_grasps, seed, gripper)


def _write_report(
    claimed, labels_dir, objects_dir, picture_objects, picture_grasps, seed, gripper
) -> ReportResult:
    """:func:`report`'s work once its page is claimed (``claimed``: the
    :class:`annotator.tools.common.ToolOutputs`)."""
    from annotator import __version__
    from annotator.tools.common import labelling_gripper, open_labels

    run = open_labels(labels_dir)
    df, manifest = run.labels, run.manifest
    hand = labelling_gripper(labels_dir, gripper, df)
    table = per_object_table(df, manifest)
    n, rate = len(df), float(df["success"].mean()) if len(df) else 0.0
    max_width = None
    state = "" if run.finished else f'<p class="unfinished"><b>This run is {_e(run.state())}.</b></p>'
    pictures, n_pictures = ("", 0)
    if picture_objects > 0:
        pictures, n_pictures = _pictures_section(
            Path(labels_dir), df, objects_dir, picture_objects, picture_grasps, seed, hand.description
        )
    now = _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
{GENERATOR}
<meta name="viewport" content="width=device-width, initial-scale=1">
<title>Grasp labels: {_e(Path(labels_dir).name)}</title>
<style>{CSS}</style><script>{IMAGE_CHECK}</script></head>
<body>
<h1>Grasp labels: {_e(Path(labels_dir).resolve())}</h1>
<p class="muted">rg2-annotator {__version__}, report written {now}</p>{state}
<p><b>{df["object_id"].nunique()}</b> objects, <b>{n}</b> grasps, <b>{rate:.1%}</b> success
({int(df["success"].sum())} held after the shake).</p>
<h2>Run</h2>{_run_section(manifest, hand.line())}
<h2>Failures</h2>{_failures_section(manifest, df)}
<h2>Objects</h2>{_objects_section(table)}
<h2>Width and score</h2>{_histograms_section(df, max_width)}
<h2>Confidence</h2>{_confidence_section(manifest, df)}
<h2>Approach directions</h2>
<p class="muted">The approach is the TCP's +z (from the gripper into the object) in the object's mesh
frame. Equal-area cells.</p>
{approach_map_svg(df)}
<h2>Pictures</h2>{pictures or "<p class='muted'>No pictures requested.</p>"}
</body></html>
"""
    out = claimed.write_text("--html", page)
    log.info("wrote %s (%d objects, %d grasps, %d pictures)", out, len(table), n, n_pictures)
    return ReportResult(out, len(table), n, n_pictures, "finished" if run.finished else run.state())
