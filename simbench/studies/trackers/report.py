"""The study's tables in seed 000's format beside the paper's numbers, and ``report.md``."""

from __future__ import annotations

import numpy as np

from eval import tracking_metrics as tm
from simbench.studies.trackers.config import ERROR_CATEGORIES, OWN_TRACKER, PAPER_COST, PAPER_ERRORS, PAPER_LOSSES, SEED_TRACKERS, TABLE_TITLES, Range, VideoDifficulty
from simbench.studies.trackers.findings import ALPHA, cost_ratios, format_cost_ratios, format_findings, loss_rate
from simbench.studies.trackers.study import StudyResult


def _f(x: float, digits: int = 2) -> str:
    return "n/a" if x is None or not np.isfinite(x) else f"{x:.{digits}f}"


def format_loss_table(result: StudyResult) -> str:
    """Table I in Markdown: per category and tracker the videos with a loss and the 99 %
    binomial interval in videos (Clopper-Pearson), seed 000's count in brackets; totals."""
    names = result.trackers
    level = result.config.confidence
    nv = result.config.videos_per_category
    lines = ["| category | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]

    def cell(k: int, n: int, p: int | None, bold: bool = False) -> str:
        r = loss_rate(k, n, level)
        txt = f"**{k}**" if bold else f"{k}"
        return f"{txt} [{r.lower * n:.1f}-{r.upper * n:.1f}]" + (f" ({p})" if p is not None else "")

    for c, row in result.losses.items():
        lines.append(f"| {c} | " + " | ".join(cell(row[n], nv, PAPER_LOSSES.get(c, {}).get(n)) for n in names) + " |")
    tot = result.total_losses()
    n_all = nv * len(result.losses)
    cells = []
    for n in names:
        p = sum(PAPER_LOSSES[c][n] for c in result.losses if n in PAPER_LOSSES.get(c, {})) if n in SEED_TRACKERS else None
        cells.append(cell(tot[n], n_all, p, bold=True))
    lines.append("| **total** | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def format_loss_variants(result: StudyResult) -> str:
    """Table I's count under the two variant definitions: strict / unrecovered."""
    names = result.trackers
    lines = ["| category | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for c in result.losses:
        lines.append(f"| {c} | " + " | ".join(f"{result.losses_strict[c][n]} / {result.losses_unrecovered[c][n]}"
                                              for n in names) + " |")
    ts, tu = tm.total_losses(result.losses_strict), tm.total_losses(result.losses_unrecovered)
    lines.append("| **total** | " + " | ".join(f"**{ts[n]} / {tu[n]}**" for n in names) + " |")
    return "\n".join(lines)


def format_error_table(result: StudyResult, category: str) -> str:
    """One of Tables II-IV in Markdown, the paper's row beside ours."""
    lines = ["| tracker | samples | lower | mean | upper | Shapiro-Wilk W (p) | normal? | videos | mean of video means, 95 % CI across videos | seed 000: samples, lower, mean, upper |",
             "|---|---:|---:|---:|---:|---:|---|---:|---|---|"]
    for n in result.trackers:
        s = result.errors[category][n]
        iv, nt = s.interval, s.normality
        p = PAPER_ERRORS[category].get(n)
        paper = f"{p[0]}, {p[1]:.2f}, {p[2]:.2f}, {p[3]:.2f}" if p else "-"
        sw = f"{_f(nt.statistic, 3)} ({nt.p_value:.1e})" if np.isfinite(nt.p_value) else "n/a"
        normal = "n/a" if not np.isfinite(nt.p_value) else ("yes" if nt.normal else "no")
        v = result.errors_across_videos.get(category, {}).get(n)
        across = f"| {v.n_finite} | {_f(v.mean)} ({_f(v.ci_low)} .. {_f(v.ci_high)}) " if v is not None else "| - | - "
        lines.append(f"| {n} | {iv.n} | {_f(iv.lower)} | {_f(iv.mean)} | {_f(iv.upper)} | {sw} | {normal} {across}| {paper} |")
    return "\n".join(lines)


def format_cost_table(result: StudyResult, tracker: str) -> str:
    """One of Tables V-VII (or the same for another tracker) in Markdown, ms."""
    lines = ["| markers | 5th pct | median | 95th pct | maximum | seed 000: 5th, median, 95th, max |",
             "|---:|---:|---:|---:|---:|---|"]
    for r in sorted((r for r in result.cost.rows if r.tracker == tracker), key=lambda r: r.n_markers):
        p = PAPER_COST.get(tracker, {}).get(r.n_markers)
        paper = ", ".join(f"{v:.3f}" for v in p) if p else "-"
        lines.append(f"| {r.n_markers} | {r.p5_ms:.4f} | {r.median_ms:.4f} | {r.p95_ms:.4f} | {r.max_ms:.4f} | {paper} |")
    return "\n".join(lines)


def format_tables(result: StudyResult) -> str:
    """All seven tables in Markdown (what the CLI prints), then the cost ratios."""
    cfg = result.config
    parts = [f"### Table I: videos with a loss, of {cfg.videos_per_category} per category -- bench [{cfg.confidence:.0%} "
             "binomial interval, videos] (seed 000)",
             "", format_loss_table(result), "",
             "Same count, strict (frames where the markers' blobs merge scored too) / unrecovered (a label still "
             "lost at its marker's last visible frame):", "", format_loss_variants(result), ""]
    for c in result.errors:
        parts += [f"### {TABLE_TITLES[c]}: prediction error, px, {cfg.confidence:.0%} CI of the mean", "",
                  format_error_table(result, c), ""]
    roman = {"alpha_beta": "Table V", "kalman_openmocap": "Table VI", "condensation": "Table VII"}
    for n in result.trackers:
        title = roman.get(n, "Table V-VII layout")
        parts += [f"### {title}: {n}, per-frame tracking cost over {result.cost.n_frames} frames, ms", "",
                  format_cost_table(result, n), ""]
    if cost_ratios(result):
        parts += ["### Cost growth: median cost at the most markers over the median at the fewest", "",
                  format_cost_ratios(result), ""]
    return "\n".join(parts)


def _discussion(result: StudyResult) -> list[str]:
    """Data-driven remarks on where the bench agrees with seed 000 and where not."""
    tot = result.total_losses()
    seeds = [n for n in SEED_TRACKERS if n in result.trackers]
    lines = _difficulty_remarks(result, seeds)
    if OWN_TRACKER in result.trackers and seeds:
        lines += _own_tracker_remarks(result, seeds, tot)
    if seeds:
        lines += _loss_remarks(result, seeds, tot)
    if result.errors:
        lines += _error_remarks(result, seeds)
    return lines + _cost_remarks(result)


def _difficulty_remarks(result: StudyResult, seeds: list[str]) -> list[str]:
    """Our mean prediction error over the paper's, per category and seed tracker (the fitted difficulty)."""
    calib = [(c, n, result.errors[c][n].interval.mean / PAPER_ERRORS[c][n][2])
             for c in ERROR_CATEGORIES if c in result.errors for n in seeds if result.errors[c][n].n]
    if not calib:
        return []
    return ["* **Difficulty.** The videos' motion was fitted to seed 000's Tables II-IV "
            "(`simbench study fit-difficulty`, see the setup); our mean prediction error over the paper's: "
            + "; ".join(f"{c} " + ", ".join(f"`{n}` {r:.2f}" for cc, n, r in calib if cc == c)
                        for c in ERROR_CATEGORIES if any(cc == c for cc, _, _ in calib)) + "."]


def _own_tracker_remarks(result: StudyResult, seeds: list[str], tot: dict[str, int]) -> list[str]:
    """The bench's own tracker against seed 000's: total lost videos (``tot``), categories where it
    loses more, and each of its lost videos (first frame, reason, which seed trackers lost it too)."""
    beaten = [n for n in seeds if tot[OWN_TRACKER] < tot[n]]
    lines = [f"* **Own tracker.** `{OWN_TRACKER}` lost {tot[OWN_TRACKER]} videos in total against "
             + ", ".join(f"`{n}` {tot[n]}" for n in seeds) + ": "
             + ("fewer than each of seed 000's trackers." if len(beaten) == len(seeds)
                else "NOT fewer than " + ", ".join(f"`{n}`" for n in seeds if n not in beaten) + ".")]
    worse = [(c, n) for c in result.losses for n in seeds if result.losses[c][OWN_TRACKER] > result.losses[c][n]]
    if worse:
        lines.append("  Categories where it loses more videos than a seed tracker: "
                     + ", ".join(f"{c} (vs `{n}`: {result.losses[c][OWN_TRACKER]} > {result.losses[c][n]})"
                                 for c, n in worse) + ".")
    own_lost = [r for r in result.videos if r.runs[OWN_TRACKER].lost]
    if own_lost:
        lines.append(f"  Its lost videos (label: first frame, reason; which seed trackers lost the same video): "
                     + "; ".join(f"{r.category} {r.index} ("
                                 + ", ".join(f"{m}: {r.runs[OWN_TRACKER].losses.first_frame[m]} "
                                             f"{r.runs[OWN_TRACKER].losses.reason_names()[m]}"
                                             for m in np.flatnonzero(r.runs[OWN_TRACKER].losses.lost))
                                 + "; " + (", ".join(f"`{n}`" for n in seeds if r.runs[n].lost) or "none") + ")"
                                 for r in own_lost) + ".")
    return lines


def _loss_remarks(result: StudyResult, seeds: list[str], tot: dict[str, int]) -> list[str]:
    """Seed 000's trackers ranked by lost videos (bench ``tot`` and paper), the hardest and easiest
    categories, and the totals under the strict and the never-recovered loss definitions."""
    rank_bench = sorted(seeds, key=lambda n: tot[n])
    paper_tot = {n: sum(PAPER_LOSSES[c][n] for c in PAPER_LOSSES if c in result.losses) for n in seeds}
    rank_paper = sorted(seeds, key=lambda n: paper_tot[n])
    lines = ["* **Ranking by losses** (same categories). Seed 000: "
             + " < ".join(f"`{n}` {paper_tot[n]}" for n in rank_paper)
             + "; bench: " + " < ".join(f"`{n}` {tot[n]}" for n in rank_bench)
             + (" -- the same order." if rank_bench == rank_paper else " -- a different order.")]
    per_cat = {c: sum(result.losses[c][n] for n in seeds) for c in result.losses}
    hard = max(per_cat, key=per_cat.get)
    easy = [c for c, v in per_cat.items() if v == 0]
    text = (f"hardest for seed 000's trackers on the bench: `{hard}` ({per_cat[hard]} losses over the three; "
            "the paper's hardest: marker swapping, 36)") if per_cat[hard] > 0 else ""
    if easy:
        text += ("; " if text else "") + (f"none of them lost a marker in {', '.join(f'`{c}`' for c in easy)}, where "
                                          "the paper counts " + ", ".join(f"{sum(PAPER_LOSSES[c].values())}" for c in easy)
                                          + " losses")
    lines.append(f"* **Categories.** {text[0].upper() + text[1:]}.")
    names = result.trackers
    strict, unrec = tm.total_losses(result.losses_strict), tm.total_losses(result.losses_unrecovered)
    lines.append("* **Definition matters.** Scoring the frames where the two swap markers' blobs merge as well "
                 "(strict) gives " + ", ".join(f"`{n}` {strict[n]}" for n in names)
                 + "; counting only losses a label never recovered from gives "
                 + ", ".join(f"`{n}` {unrec[n]}" for n in names) + ".")
    return lines


def _error_remarks(result: StudyResult, seeds: list[str]) -> list[str]:
    """Which seed tracker has the smallest / largest mean prediction error (px) per category, our
    range of means against the paper's, and how many error samples Shapiro-Wilk finds non-normal."""
    lines = []
    agree = []
    for c, row in result.errors.items():
        m = {n: row[n].interval.mean for n in seeds if row[n].n}
        if len(m) >= 2:
            agree.append((c, min(m, key=m.get), max(m, key=m.get)))
    if agree:
        lines.append("* **Prediction errors.** Smallest / largest mean among seed 000's trackers: "
                     + "; ".join(f"{c}: `{lo}` / `{hi}`" for c, lo, hi in agree)
                     + " (paper: `alpha_beta` / `condensation` in every category). Our means are "
                     + ", ".join(f"{c} {min(row[n].interval.mean for n in seeds if row[n].n):.1f}-"
                                 f"{max(row[n].interval.mean for n in seeds if row[n].n):.1f} px"
                                 for c, row in result.errors.items() if any(row[n].n for n in seeds))
                     + " against the paper's 7-39, 11-40 and 3-23 px.")
    nonnormal = sum(1 for row in result.errors.values() for s in row.values() if s.n >= 3 and not s.normality.normal)
    total = sum(1 for row in result.errors.values() for s in row.values() if s.n >= 3)
    lines.append(f"* **Normality.** Shapiro-Wilk rejects normality (p < 0.01) for {nonnormal} of {total} error "
                 "samples, as the paper found; the t intervals lean on the central limit theorem as the paper's do.")
    return lines


def _cost_remarks(result: StudyResult) -> list[str]:
    """Each tracker's median cost at the most markers over that at the fewest (and the paper's ratio)."""
    ratios = cost_ratios(result)
    if not ratios:
        return []
    return ["* **Cost.** Median cost at the most markers over that at the fewest: "
            + ", ".join(f"`{n}` x{o:.1f}" + (f" (paper x{p:.1f})" if p else "") for n, (o, p) in ratios.items())
            + ". The bench's trackers are vectorised over markers, so a fixed per-frame overhead weighs more "
            "than the per-marker work and the cost grows far less than OpenMoCap's per-marker loops. Maxima "
            "are single frames disturbed by the (shared) machine."]


_STATIC_DISCUSSION = """\
Why the numbers may differ from the paper's, beyond the videos being different draws:

* **Trackers.** Seed 000's three trackers (`alpha_beta`, `kalman_openmocap`,
  `condensation`) are re-implementations of OpenMoCap's own (the software the paper
  evaluates; its source gives what the paper leaves out: alpha-beta's fixed search
  circle of 5 % of the image diagonal, the Kalman filter's Q, R and search radius, the
  CONDENSATION diffusion), in `mocap/trackers/openmocap.py`. They share the bench's
  gated assignment, which for one labelled marker is OpenMoCap's nearest detection in
  the search circle. The bench's own variants are separate rows: `alpha_beta_adaptive`
  (a search area that grows with the residuals and the speed, starting at the same
  40 px circle), `kalman` (the bench's tuned Kalman filter), `condensation_drift`
  (particles with a drift velocity) and `imm`.
* **Difficulty.** Seed 000 gives no marker speeds. The zigzag and acceleration motions
  were fitted so that its three trackers' mean prediction errors match Tables II-IV
  (`simbench/studies/trackers/fit.py`): the markers move about 20-28 px per frame. The
  occlusion and swap videos have no error table to fit: their markers move at the
  fitted slow speeds, the barrier is 30-120 px wide, and their loss counts are not
  calibrated to anything.
* **Detections.** The blobs are rendered through the camera model and found by the
  pipeline's detector, within about 0.1 px of the truth; the errors are those of the
  motion models.
* **Loss definition.** The paper does not define a loss; ours is strict (one frame with
  the estimate more than the loss radius from a visible marker counts, even if the
  label picks its marker up again the next frame), hence the two variants above.
* **Swapping.** As in the paper's Fig. 5, one marker is labelled and the other is not
  ("NULL"); a label that takes the NULL marker's blob is a loss.
* **Cost.** Absolute times are not comparable (numpy on a shared 2-core machine here,
  OpenMoCap on 2010 hardware there); how the cost grows with the marker count is.
"""


def describe_difficulty(d: VideoDifficulty) -> list[str]:
    """Markdown bullets of the videos' motion (``config.difficulty``)."""
    def r(x: Range, unit: str = "") -> str:
        return f"{x[0]:g}-{x[1]:g}{unit}"

    out = [f"* **{c}**: zigzag at {r(z.speed_px_per_frame, ' px/frame')}, legs of {r(z.leg_frames)} frames, turns of "
           f"{r(z.turn_deg, ' deg')}" for c, z in (("slow", d.slow), ("rapid", d.rapid))]
    a = d.acceleration
    out.append(f"* **acceleration**: speeding up from {r(a.start_speed_px_per_frame)} to {r(a.top_speed_px_per_frame, ' px/frame')} "
               f"(ramp power {r(a.ramp_power)}, bent up to {a.bend_deg:g} deg), the same braking, or oscillating at up to "
               f"{r(a.top_speed_px_per_frame, ' px/frame')} with a period of {r(a.period_s, ' s')}")
    o = d.occlusion
    out.append(f"* **occlusion**: {r(o.speed_px_per_frame, ' px/frame')} on a straight, arc or wavy path behind a barrier "
               f"{r(o.barrier_width_px)} px wide and {r(o.barrier_height_px)} px tall")
    w = d.swap
    out.append(f"* **swap**: {'a labelled and an unlabelled (NULL) marker' if w.labelled == 1 else 'two labelled markers'} at "
               f"{r(w.speed_px_per_frame, ' px/frame')}, paths crossing at {r(w.crossing_angle_deg, ' deg')}, "
               f"{r(w.miss_px, ' px')} apart")
    if d.detection_noise_px > 0:
        out.append(f"* detection noise added: {d.detection_noise_px:g} px per axis")
    return out


def format_report(result: StudyResult, frames: dict[str, tuple[str, str]] | None = None) -> str:
    """The Markdown report: setup, the seven tables beside the paper's, plots, discussion."""
    cfg = result.config
    n_videos = len(result.videos)
    parts = [
        "# Tracker study: seed 000's experiments on the bench", "",
        f"{n_videos} rendered videos ({cfg.videos_per_category} per category: {', '.join(cfg.categories)}), "
        f"{cfg.n_frames} frames each at {cfg.fps:g} fps, 640x480, one webcam {cfg.plane_distance_m:g} m from the "
        f"markers' plane, sensor mode `{cfg.sensor_mode}`, exposure {cfg.exposure_ms:g} ms, motion blur "
        f"{'on' if cfg.motion_blur else 'off'}; seed {cfg.seed}; trackers: {', '.join(f'`{n}`' for n in result.trackers)}.",
        f"Videos took {result.seconds.get('videos', 0):.0f} s ({cfg.workers} worker(s)), the cost tables "
        f"{result.seconds.get('cost', 0):.0f} s. Regenerate with "
        f"`simbench study trackers --out DIR --videos {cfg.videos_per_category} --seed {cfg.seed}`.", "",
        "Motion (image speeds; zigzag and acceleration fitted to seed 000's Tables II-IV by "
        "`simbench study fit-difficulty`, occlusion and swap at the fitted slow speeds):", "",
        *describe_difficulty(cfg.difficulty), "",
        "## Definitions", "",
        f"* **Loss** (Table I): a video counts one loss for a tracker when, at some frame after the first "
        f"(the labels start at the true positions, as seed 000's manual initialisation), a label whose marker is "
        f"visible (at least {cfg.min_visible_fraction:.0%} of its area shows, and no other marker within "
        f"{cfg.merge_px:g} px, where the two blobs merge into one) is declared lost, or its estimate is "
        f"more than **{cfg.loss_radius_px:g} px** (about 1.7 blob diameters) from the marker, or it took a blob "
        f"nearer to the other marker while the two markers were more than {cfg.loss_radius_px:g} px apart. "
        "Per label and video: `losses.csv` and `videos/*.json`; per frame: `videos/*.npz`.",
        "* **Prediction error** (Tables II-IV): distance, px, between a label's prediction (before the frame's "
        "update) and the detection associated with it, over every frame after the first where it had one, pooled "
        "over the videos of the category in which that tracker lost nothing. Interval: Student's t, "
        f"{cfg.confidence:.0%}, of the mean; Shapiro-Wilk on the same sample (scipy).",
        f"* **Cost** (Tables V-VII): wall time of one predict-associate-update step of all markers, over "
        f"{result.cost.n_frames} frames of smooth synthetic paths (`simbench.benchmarks.trackers`), after the videos, "
        "in the same run.", "",
        "## Seed 000's findings, checked", "",
        f"Each finding tested on the bench's videos at the {1 - ALPHA:.0%} level: losses by the exact McNemar test "
        "of two trackers on the same videos (binomial intervals: Clopper-Pearson), prediction errors by Welch's t-test "
        "(frames taken as independent, as the paper's t intervals take them). *Reproduced*: the claim holds "
        "significantly in every part; *not reproduced*: the opposite holds significantly in some part; otherwise "
        "*not decidable at this N*. The last column asks the same of the paper's own figures.", "",
        format_findings(result), "",
        "## Results (bench, with seed 000's numbers in brackets or beside)", "",
        format_tables(result),
        "## Plots", "",
        "![losses](plots/losses.png)", "", "![prediction errors](plots/prediction_errors.png)", "",
        "![cost](plots/cost.png)", "",
    ]
    if frames:
        parts += ["## Rendered frames", "",
                  "First video of each category, at a telling frame: raw, and brightened with the true path (dashed), "
                  "each tracker's search circle (around its prediction) and estimate (dot), like the paper's Figs. 3-5.", ""]
        for c, (raw, ann) in frames.items():
            parts += [f"**{c}**: [raw](frames/{raw})", "", f"![{c}](frames/{ann})", ""]
    parts += ["## Discussion", ""] + _discussion(result) + ["", _STATIC_DISCUSSION]
    return "\n".join(parts) + "\n"
