"""``simbench report DB --out DIR``: HTML and Markdown report of a sweep.

Reads the results database written by :mod:`simbench.sweeps.sweep` and writes
``report.md``, ``report.html`` and ``plots/*.png``:

* every metric against every swept factor (each run a dot, the mean a line);
* heatmaps of the key metrics over each pair of factors (mean over the others);
* trackers side by side (when the tracker is a factor);
* the per-frame marker error of the worst runs (from the Parquet per-frame tables);
* the worst runs and the failed runs, linked to their outputs (report, contact sheet
  with frames, videos).

One content list is rendered twice, as Markdown and as HTML, so the two never drift.
"""

from __future__ import annotations

import html
import json
import math
import os
import re
from dataclasses import dataclass
from datetime import datetime, timezone
from itertools import combinations
from pathlib import Path

import duckdb
import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from simbench.errors import SimbenchInputError
from simbench.sweeps.results_db import STATUS_OK, ResultsDB

# Metrics shown first and used for heatmaps, tracker plots and the worst-runs ranking,
# with the direction that is worse.
KEY_METRICS = {
    "markers.rmse_mm": "higher",
    "markers.reconstructed_fraction": "lower",
    "markers.losses_2d": "higher",
    "markers.label_swaps": "higher",
    "markers.p95_error_mm": "higher",
    "skeleton.joint_angle_rmse_deg": "higher",
}
HIDDEN_METRICS = ("run.frames", "run.cameras")
TRACKER_FIELDS = ("markers_pipeline.tracker", "tracker")


# ---------------------------------------------------------------------------- document model
@dataclass(frozen=True)
class Link:
    text: str
    href: str


Cell = str | Link


@dataclass(frozen=True)
class Block:
    kind: str  # "h1" | "h2" | "p" | "table" | "img"
    text: str = ""
    header: tuple[str, ...] = ()
    rows: tuple[tuple[Cell, ...], ...] = ()


def _md_cell(c: Cell) -> str:
    s = f"[{c.text}]({c.href})" if isinstance(c, Link) else str(c)
    return s.replace("|", "\\|").replace("\n", " ")


def to_markdown(blocks: list[Block]) -> str:
    out: list[str] = []
    for b in blocks:
        if b.kind == "h1":
            out += [f"# {b.text}", ""]
        elif b.kind == "h2":
            out += [f"## {b.text}", ""]
        elif b.kind == "p":
            out += [b.text, ""]
        elif b.kind == "img":
            out += [f"![{b.header[0] if b.header else ''}]({b.text})", ""]
        elif b.kind == "table":
            out.append("| " + " | ".join(b.header) + " |")
            out.append("|" + "|".join("---" for _ in b.header) + "|")
            out += ["| " + " | ".join(_md_cell(c) for c in r) + " |" for r in b.rows]
            out.append("")
    return "\n".join(out)


def _inline_html(text: str) -> str:
    """Markdown `code` spans to <code>; everything else escaped."""
    parts = re.split(r"`([^`]*)`", text)
    return "".join(f"<code>{html.escape(p)}</code>" if i % 2 else html.escape(p) for i, p in enumerate(parts))


def to_html(blocks: list[Block], title: str) -> str:
    body: list[str] = []
    for b in blocks:
        if b.kind in ("h1", "h2"):
            body.append(f"<{b.kind}>{_inline_html(b.text)}</{b.kind}>")
        elif b.kind == "p":
            body.append(f"<p>{_inline_html(b.text)}</p>")
        elif b.kind == "img":
            alt = html.escape(b.header[0] if b.header else "")
            body.append(f'<p><a href="{html.escape(b.text)}"><img src="{html.escape(b.text)}" alt="{alt}"></a></p>')
        elif b.kind == "table":
            head = "".join(f"<th>{html.escape(h)}</th>" for h in b.header)
            rows = []
            for r in b.rows:
                cells = []
                for c in r:
                    cells.append(f'<td><a href="{html.escape(c.href)}">{html.escape(c.text)}</a></td>' if isinstance(c, Link)
                                 else f"<td>{_inline_html(str(c))}</td>")
                rows.append("<tr>" + "".join(cells) + "</tr>")
            body.append(f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>")
    style = ("body{font-family:system-ui,sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}"
             "table{border-collapse:collapse;margin:1em 0;font-size:0.9em}th,td{border:1px solid #ccc;padding:3px 8px;text-align:left}"
             "th{background:#f2f2f2}img{max-width:100%;border:1px solid #eee}code{background:#f6f6f6;padding:0 3px}")
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


# ---------------------------------------------------------------------------- data
@dataclass
class SweepData:
    name: str
    description: str
    runs: pd.DataFrame           # one row per run: run columns, factor columns, metric columns
    factors: dict[str, list]     # swept factor -> levels in file order
    metrics: list[str]           # metric columns, key metrics first
    db: ResultsDB


def _fmt(v) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "—"
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def load_sweep_data(db_path: str | Path, sweep: str | None = None) -> SweepData:
    db = ResultsDB(db_path)
    if not db.path.is_file():
        raise SimbenchInputError(f"{db.path}: no results database here; run `simbench sweep SWEEP.toml --db {db.path}` first")
    try:  # results a sweep stored while the database was locked
        db.reconcile()
    except duckdb.Error:
        pass  # a running sweep holds it; report what the database has
    sweeps = db.sweeps()
    names = list(sweeps["sweep"])
    if not names:
        raise SimbenchInputError(f"{db.path}: the database holds no sweep yet; run `simbench sweep` first")
    if sweep is None:
        if len(names) > 1:
            raise SimbenchInputError(f"{db.path}: holds several sweeps ({', '.join(names)}); choose one with --sweep NAME")
        sweep = names[0]
    if sweep not in names:
        raise SimbenchInputError(f"{db.path}: --sweep {sweep!r} not found; the database holds: {', '.join(names)}")
    row = sweeps[sweeps["sweep"] == sweep].iloc[0]
    wide = db.metrics_wide(sweep)
    levels: dict[str, list] = row["factor_levels"]
    # A factor is swept when its runs show more than one level.
    factors = {f: [lv for lv in lvls if (wide[f] == lv).any()] for f, lvls in levels.items() if f in wide and wide[f].nunique() > 1}
    metric_cols = [c for c in wide.columns if "." in c and c not in levels and c not in HIDDEN_METRICS]
    metric_cols = [c for c in metric_cols if pd.api.types.is_numeric_dtype(wide[c])]
    key = [m for m in KEY_METRICS if m in metric_cols]
    metrics = key + sorted(m for m in metric_cols if m not in key)
    return SweepData(sweep, str(row["spec"].get("description", "")), wide, factors, metrics, db)


def _safe(s: str) -> str:
    return re.sub(r"[^A-Za-z0-9_-]+", "_", s).strip("_")


def _is_numeric_axis(levels: list) -> bool:
    return len(levels) > 8 and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in levels)


def _varying(d: SweepData, ok: pd.DataFrame) -> list[str]:
    return [m for m in d.metrics if ok[m].notna().any() and ok[m].nunique(dropna=True) > 1]


# ---------------------------------------------------------------------------- plots
def plot_metric_vs_factor(d: SweepData, ok: pd.DataFrame, factor: str, metrics: list[str], path: Path) -> None:
    """One panel per metric: every run a dot (jittered), the mean per level a line."""
    n = len(metrics)
    ncol = min(3, n)
    nrow = math.ceil(n / ncol)
    fig = Figure(figsize=(4.6 * ncol, 3.3 * nrow))
    levels = d.factors[factor]
    numeric = _is_numeric_axis(levels)
    rng = np.random.default_rng(0)  # jitter only
    for i, m in enumerate(metrics):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        if numeric:
            ax.scatter(ok[factor].astype(float), ok[m], s=14, alpha=0.7)
            ax.set_xlabel(factor)
        else:
            pos = {lv: k for k, lv in enumerate(levels)}
            x = ok[factor].map(pos).astype(float)
            ax.scatter(x + rng.uniform(-0.12, 0.12, len(x)), ok[m], s=14, alpha=0.6, color="tab:blue", label="run")
            means = [ok.loc[ok[factor] == lv, m].mean() for lv in levels]
            ax.plot(range(len(levels)), means, "o-", color="tab:red", lw=1.5, ms=5, label="mean")
            ax.set_xticks(range(len(levels)))
            ax.set_xticklabels([str(lv) for lv in levels], rotation=20 if max(len(str(v)) for v in levels) > 8 else 0,
                               ha="right" if max(len(str(v)) for v in levels) > 8 else "center", fontsize=8)
            ax.set_xlim(-0.5, len(levels) - 0.5)
        worse = KEY_METRICS.get(m)
        ax.set_title(m + (f"  ({worse} is worse)" if worse else ""), fontsize=9)
        ax.grid(alpha=0.3)
        if i == 0 and not numeric:
            ax.legend(fontsize=7)
    fig.suptitle(f"{d.name}: metrics against {factor}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def plot_heatmaps(d: SweepData, ok: pd.DataFrame, fx: str, fy: str, metrics: list[str], path: Path) -> None:
    """Mean of each metric over the other factors, for every level pair of two factors."""
    n = len(metrics)
    ncol = min(2, n)
    nrow = math.ceil(n / ncol)
    lx, ly = d.factors[fx], d.factors[fy]
    fig = Figure(figsize=(max(5.0, 1.3 * len(lx) + 2.5) * ncol, max(3.2, 0.6 * len(ly) + 2.0) * nrow))
    for i, m in enumerate(metrics):
        ax = fig.add_subplot(nrow, ncol, i + 1)
        grid = np.full((len(ly), len(lx)), np.nan)
        for a, vy in enumerate(ly):
            for b, vx in enumerate(lx):
                sel = ok.loc[(ok[fx] == vx) & (ok[fy] == vy), m]
                grid[a, b] = sel.mean() if sel.notna().any() else np.nan
        cmap = "viridis_r" if KEY_METRICS.get(m) == "higher" else "viridis"
        im = ax.imshow(grid, cmap=cmap, aspect="auto")
        fig.colorbar(im, ax=ax, fraction=0.046, pad=0.03)
        finite = grid[np.isfinite(grid)]
        mid = (finite.min() + finite.max()) / 2 if finite.size else 0.0
        for a in range(len(ly)):
            for b in range(len(lx)):
                v = grid[a, b]
                dark = (v > mid) if cmap == "viridis_r" else (v < mid)
                ax.text(b, a, _fmt(float(v)), ha="center", va="center", fontsize=8, color="white" if dark else "black")
        ax.set_xticks(range(len(lx)))
        ax.set_xticklabels([str(v) for v in lx], fontsize=8, rotation=20, ha="right")
        ax.set_yticks(range(len(ly)))
        ax.set_yticklabels([str(v) for v in ly], fontsize=8)
        ax.set_xlabel(fx, fontsize=8)
        ax.set_ylabel(fy, fontsize=8)
        worse = KEY_METRICS.get(m)
        ax.set_title(f"{m} (mean{', ' + worse + ' is worse' if worse else ''})", fontsize=9)
    fig.suptitle(f"{d.name}: {fy} x {fx}", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def plot_trackers(d: SweepData, ok: pd.DataFrame, tracker: str, metrics: list[str], path: Path) -> None:
    """Grouped bars: one group per combination of the other factors, one bar per tracker."""
    trackers = d.factors[tracker]
    others = [f for f in d.factors if f != tracker]
    if others:
        groups = ok[others].drop_duplicates()
        groups = groups.sort_values(by=others, key=lambda s: s.map({v: i for i, v in enumerate(d.factors[s.name])}))
        glabels = ["\n".join(str(v) for v in row) for row in groups.itertuples(index=False)]
        gmasks = [np.logical_and.reduce([ok[f] == v for f, v in zip(others, row)]) for row in groups.itertuples(index=False)]
    else:
        glabels, gmasks = ["all runs"], [np.ones(len(ok), bool)]
    n = len(metrics)
    fig = Figure(figsize=(max(7.0, 0.45 * len(glabels) * max(1, len(trackers)) + 3), 2.6 * n + 1.0))
    width = 0.8 / max(1, len(trackers))
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple", "tab:brown", "tab:pink", "tab:gray"]
    for i, m in enumerate(metrics):
        ax = fig.add_subplot(n, 1, i + 1)
        for k, tr in enumerate(trackers):
            vals = [ok.loc[mask & (ok[tracker] == tr), m].mean() for mask in gmasks]
            ax.bar(np.arange(len(glabels)) + (k - (len(trackers) - 1) / 2) * width, vals, width,
                   label=str(tr), color=colors[k % len(colors)])
        ax.set_xticks(range(len(glabels)))
        ax.set_xlim(-0.5, len(glabels) - 0.5)
        ax.set_xticklabels(glabels if i == n - 1 else [""] * len(glabels), fontsize=8)
        worse = KEY_METRICS.get(m)
        ax.set_title(m + (f" ({worse} is worse)" if worse else ""), fontsize=9)
        ax.grid(alpha=0.3, axis="y")
        for g, mask in enumerate(gmasks):  # say so where a bar is missing because nothing was measured
            for k, tr in enumerate(trackers):
                if not np.isfinite(ok.loc[mask & (ok[tracker] == tr), m].mean()):
                    ax.text(g + (k - (len(trackers) - 1) / 2) * width, 0, "n/a", ha="center", va="bottom", fontsize=7,
                            rotation=90, color="0.4")
    handles, labels = fig.axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="upper center", ncol=len(trackers), fontsize=8, title=tracker, title_fontsize=8,
               bbox_to_anchor=(0.5, 0.97))
    if others:
        fig.supxlabel(" / ".join(others), fontsize=9)
    fig.suptitle(f"{d.name}: trackers side by side", fontsize=11)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    fig.savefig(path, dpi=90)


def plot_worst_per_frame(frames: pd.DataFrame, labels: dict[str, str], path: Path) -> None:
    """Median and worst marker error per frame of each of the worst runs."""
    fig = Figure(figsize=(9, 4.2))
    ax0 = fig.add_subplot(1, 2, 1)
    ax1 = fig.add_subplot(1, 2, 2, sharex=ax0)
    for rid, lab in labels.items():
        f = frames[frames["run_id"] == rid]
        if f.empty:
            continue
        g = f.groupby("time_s")["error_mm"]
        line = ax0.plot(g.median().index, g.median().values, lw=1.2, label=lab)[0]
        ax1.plot(g.max().index, g.max().values, lw=1.2, color=line.get_color())
    ax0.set_title("median marker error per frame", fontsize=9)
    ax1.set_title("worst marker error per frame", fontsize=9)
    for ax in (ax0, ax1):
        ax.set_xlabel("time (s)")
        ax.set_ylabel("mm")
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
    ax0.legend(fontsize=7)
    fig.suptitle("worst runs: per-frame 3D marker error (gaps not drawn)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)


# ---------------------------------------------------------------------------- the report
def _run_links(d: SweepData, run: pd.Series, out_dir: Path) -> list[Cell]:
    if not run.get("out_dir"):
        return ["(outputs not kept)"]
    run_dir = (d.db.store.root / str(run["out_dir"])).resolve()
    rel = os.path.relpath(run_dir, out_dir.resolve())
    cells: list[Cell] = []
    for name, text in (("report.md", "report"), ("contact_sheet.png", "frames"), ("videos", "videos")):
        if (run_dir / name).exists():
            cells.append(Link(text, f"{rel}/{name}"))
    return cells or ["(missing)"]


def _worst_order(ok: pd.DataFrame, metrics: list[str]) -> tuple[pd.DataFrame, str]:
    for m, worse in KEY_METRICS.items():
        if m in metrics and ok[m].notna().any():
            key = ok[m].fillna(np.inf if worse == "higher" else -np.inf)
            return ok.assign(_k=key).sort_values("_k", ascending=(worse == "lower")).drop(columns="_k"), m
    return ok, ""


def write_sweep_report(db_path: str | Path, out: str | Path, sweep: str | None = None, n_worst: int = 8) -> Path:
    """Write ``report.md``, ``report.html`` and ``plots/`` for one sweep; return the Markdown path."""
    d = load_sweep_data(db_path, sweep)
    out = Path(out)
    plots = out / "plots"
    plots.mkdir(parents=True, exist_ok=True)
    runs = d.runs
    ok = runs[runs["status"] == STATUS_OK].copy()
    bad = runs[runs["status"] != STATUS_OK]
    varying = _varying(d, ok) if len(ok) else []
    key_varying = [m for m in KEY_METRICS if m in varying][:4] or varying[:4]
    blocks = _overview_blocks(d, ok, bad)
    if len(ok):
        blocks += _metrics_table_blocks(d, ok)
    if varying and d.factors:
        blocks += _factor_plot_blocks(d, ok, varying, plots)
    blocks += _heatmap_blocks(d, ok, key_varying, plots)
    blocks += _tracker_blocks(d, ok, key_varying, plots)
    blocks += _worst_run_blocks(d, ok, n_worst, out, plots)
    if len(bad):
        blocks += _failed_run_blocks(d, bad)
    blocks += _all_run_blocks(d)

    md = out / "report.md"
    md.write_text(to_markdown(blocks))
    (out / "report.html").write_text(to_html(blocks, f"Sweep report: {d.name}"))
    (out / "summary.json").write_text(json.dumps({
        "sweep": d.name, "runs": int(len(runs)), "ok": int(len(ok)), "failed": int(len(bad)),
        "factors": d.factors, "metrics": d.metrics,
        "plots": sorted(p.name for p in plots.glob("*.png")),
    }, indent=2, default=str))
    return md


def _overview_blocks(d: SweepData, ok: pd.DataFrame, bad: pd.DataFrame) -> list[Block]:
    """Title, description, run counts, wall time (s), factors and levels, and the versions of the first run.

    ``ok`` and ``bad`` are the runs (rows of ``d.runs``) that succeeded and failed.
    """
    blocks: list[Block] = [Block("h1", f"Sweep report: {d.name}")]
    if d.description:
        blocks.append(Block("p", d.description))
    wall = ""
    all_runs = d.db.runs(d.name)
    if len(all_runs):
        t0, t1 = all_runs["started_at"].min(), all_runs["ended_at"].max()
        wall = (f"; {all_runs['duration_s'].sum():.0f} s of run time in workers, "
                f"{(t1 - t0).total_seconds():.0f} s from first start ({t0:%Y-%m-%d %H:%M:%S} UTC) to last end")
    blocks.append(Block("p", f"Database `{d.db.path}`: {len(d.runs)} runs, {len(ok)} ok, {len(bad)} failed{wall}. "
                             f"Factors: " + "; ".join(f"`{f}` = {', '.join(map(str, lv))}" for f, lv in d.factors.items())
                             + f". Generated {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC."))
    if len(all_runs):
        v = all_runs["versions"].iloc[0]
        blocks.append(Block("p", "Versions: " + ", ".join(f"{k} {val}" for k, val in v.items())))
    return blocks


def _metrics_table_blocks(d: SweepData, ok: pd.DataFrame) -> list[Block]:
    """Each metric's min, median and max (in the metric's own units) over the successful runs ``ok``."""
    rows = []
    for m in d.metrics:
        col = ok[m]
        rows.append((f"`{m}`", KEY_METRICS.get(m, ""), _fmt(float(col.min())), _fmt(float(col.median())),
                     _fmt(float(col.max())), str(int(col.notna().sum()))))
    return [Block("h2", "Metrics over all runs"),
            Block("table", header=("metric", "worse", "min", "median", "max", "runs"), rows=tuple(rows))]


def _factor_plot_blocks(d: SweepData, ok: pd.DataFrame, varying: list[str], plots: Path) -> list[Block]:
    """One plot per factor (``plots/metrics_vs_<factor>.png``) of the ``varying`` metrics against its levels."""
    blocks = [Block("h2", "Each metric against each factor")]
    for f in d.factors:
        p = plots / f"metrics_vs_{_safe(f)}.png"
        plot_metric_vs_factor(d, ok, f, varying, p)
        blocks.append(Block("img", f"plots/{p.name}", header=(f"metrics vs {f}",)))
    return blocks


def _heatmap_blocks(d: SweepData, ok: pd.DataFrame, key_varying: list[str], plots: Path) -> list[Block]:
    """Heatmaps of the ``key_varying`` metrics over each pair of categorical factors (none with fewer than two)."""
    cat = [f for f in d.factors if not _is_numeric_axis(d.factors[f])]
    if not (key_varying and len(cat) >= 2):
        return []
    blocks = [Block("h2", "Heatmaps over two factors"),
              Block("p", "Each cell is the mean over the runs with those two levels (and every level of the other "
                         "factors); yellow is better in every panel, a dash means nothing was measured.")]
    for fx, fy in combinations(cat, 2):
        p = plots / f"heatmap_{_safe(fy)}__{_safe(fx)}.png"
        plot_heatmaps(d, ok, fx, fy, key_varying, p)
        blocks.append(Block("img", f"plots/{p.name}", header=(f"{fy} x {fx}",)))
    return blocks


def _tracker_blocks(d: SweepData, ok: pd.DataFrame, key_varying: list[str], plots: Path) -> list[Block]:
    """If a factor is the tracker: its plot (``plots/trackers.png``) and each tracker's mean key metrics."""
    tracker = next((f for f in d.factors if f in TRACKER_FIELDS or f.endswith(".tracker")), None)
    if not (tracker and key_varying):
        return []
    p = plots / "trackers.png"
    plot_trackers(d, ok, tracker, key_varying, p)
    rows = []
    for tr in d.factors[tracker]:
        sel = ok[ok[tracker] == tr]
        rows.append((str(tr), str(len(sel)), *(_fmt(float(sel[m].mean())) for m in key_varying)))
    return [Block("h2", "Trackers side by side"), Block("img", f"plots/{p.name}", header=("trackers",)),
            Block("table", header=(tracker, "runs", *(f"mean {m}" for m in key_varying)), rows=tuple(rows))]


def _worst_run_blocks(d: SweepData, ok: pd.DataFrame, n_worst: int, out: Path, plots: Path) -> list[Block]:
    """The ``n_worst`` worst successful runs (factors, key metrics, links to their outputs under ``out``),
    then the per-frame error plot of those that reconstructed anything."""
    worst, by = _worst_order(ok, d.metrics)
    worst = worst.head(n_worst)
    if not len(worst):
        return []
    blocks = [Block("h2", f"Worst {len(worst)} runs" + (f" by `{by}`" if by else ""))]
    shown = [m for m in KEY_METRICS if m in d.metrics][:4]
    rows = []
    for i, (_, r) in enumerate(worst.iterrows(), 1):
        links = _run_links(d, r, out)
        rows.append((str(i), f"`{r['run_id']}`", ", ".join(f"{f}={r[f]}" for f in d.factors),
                     *(_fmt(float(r[m])) for m in shown), *links))
    n_links = max(len(r) for r in rows) - 3 - len(shown)
    blocks.append(Block("table", header=("#", "run", "factors", *shown, *(["outputs"] + [""] * (n_links - 1) if n_links else [])),
                        rows=tuple(r + ("",) * (3 + len(shown) + n_links - len(r)) for r in rows)))
    return blocks + _worst_per_frame_blocks(d, ok, plots)


def _worst_per_frame_blocks(d: SweepData, ok: pd.DataFrame, plots: Path) -> list[Block]:
    """Per-frame 3D marker error (mm) of the five worst runs that reconstructed any marker (``plots/worst_runs_per_frame.png``)."""
    ranked, _ = _worst_order(ok, d.metrics)
    frames = d.db.per_frame(list(ranked["run_id"]))
    with_data = set(frames.loc[np.isfinite(frames["error_mm"].to_numpy(float)), "run_id"]) if len(frames) else set()
    pick = ranked[ranked["run_id"].isin(with_data)].head(5)
    if not len(pick):
        return []
    labels = {r["run_id"]: f"{r['run_id'][:8]} " + " ".join(str(r[f]) for f in d.factors) for _, r in pick.iterrows()}
    p = plots / "worst_runs_per_frame.png"
    plot_worst_per_frame(frames, labels, p)
    return [Block("p", "Per-frame 3D marker error of the worst runs that reconstructed any marker "
                       "(from the per-frame Parquet tables):"),
            Block("img", f"plots/{p.name}", header=("worst runs per frame",))]


def _failed_run_blocks(d: SweepData, bad: pd.DataFrame) -> list[Block]:
    """The failed runs ``bad``: id, factors and the first line of the error."""
    rows = tuple((f"`{r['run_id']}`", ", ".join(f"{f}={r[f]}" for f in d.factors),
                  (r["error"] or "").splitlines()[0] if r["error"] else "") for _, r in bad.iterrows())
    return [Block("h2", f"Failed runs ({len(bad)})"), Block("table", header=("run", "factors", "error"), rows=rows)]


def _all_run_blocks(d: SweepData) -> list[Block]:
    """Every run in run order: factors, status, key metrics and duration (s)."""
    shown = [m for m in KEY_METRICS if m in d.metrics][:4]
    rows = tuple((str(int(r["run_index"])), f"`{r['run_id']}`", *(str(r[f]) for f in d.factors), r["status"],
                  *(_fmt(float(r[m])) if r["status"] == STATUS_OK else "" for m in shown), f"{r['duration_s']:.1f}")
                 for _, r in d.runs.sort_values("run_index").iterrows())
    return [Block("h2", "All runs"), Block("table", header=("#", "run", *d.factors, "status", *shown, "s"), rows=rows)]
