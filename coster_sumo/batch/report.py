"""Reports of batch commands: Markdown + HTML pages with PNG plots (matplotlib, Agg).

``coster-sumo regress`` -> ``OUT/report.md``, ``OUT/report.html``, ``OUT/plots/*.png`` and
``OUT/examples/<run_key>.png``: the per-planner table (RCR / CR / ORR with Wilson 95 % intervals),
failed runs with their reasons, per-planner failure examples (collision, off-road, route not
completed), and the distributions of impact angle and relative speed at first contact.

``coster-sumo eval scenarios`` -> ``OUT/metrics.json``, ``OUT/metrics.md``, ``OUT/metrics.png``:
SUR, CR, ORR, VDD, ADD, CSD, CPD and circular CPD per generator; skipped methods with the reason.
"""

from __future__ import annotations

import html
import json
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from coster_sumo.batch.generator_summary import EvalSummary, GeneratorResult, SkippedGenerator
from coster_sumo.batch.store import ResultRow
from coster_sumo.batch.summaries import RegressionSummary
from coster_sumo.infra.atomic import write_text
from coster_sumo.metrics import MetricValue

EXAMPLES_PER_PLANNER = 3



def _legend(ax: Any, **kwargs: Any) -> None:
    """A legend where something is labelled: a planner without contacts draws nothing, and
    matplotlib would warn "No artists with labels found" on the console of a quiet run."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kwargs)

def _pct(rate: MetricValue) -> str:
    """A rate in the regression's table: percent and its Wilson interval."""
    if rate.value is None:
        return "n/a"
    return f"{100 * rate.value:.1f}% [{100 * (rate.ci_low or 0.0):.1f}, {100 * (rate.ci_high or 0.0):.1f}]"


def _fmt(x: Any, digits: int = 3) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, float):
        return f"{x:.{digits}f}"
    return str(x)


def _plt() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ============================================================================ regression


def _pct_of(rate: MetricValue) -> str:
    """A rate in a report's table: percent, its Wilson interval, k/n."""
    if rate.value is None:
        return "n/a"
    return (f"{100 * rate.value:.1f}% [{100 * (rate.ci_low or 0.0):.1f}, {100 * (rate.ci_high or 0.0):.1f}] "
            f"({rate.k}/{rate.n})")


def defect_table(summary: RegressionSummary) -> tuple[list[str], list[list[str]]]:
    """The headline table of a regression: per planner, the defect rate beside the unavoidable-contact rate."""
    head = ["planner", "defect rate (contact in an avoidable variant)", "unavoidable-contact rate",
            "RCR avoidable", "RCR unavoidable"]
    rows = []
    for name, p in summary.planners.items():
        d = p.defects
        rows.append([name, _pct_of(d.defect_rate), _pct_of(d.unavoidable_contact_rate),
                     _pct_of(d.avoidable.RCR), _pct_of(d.unavoidable.RCR)])
    return head, rows


def avoidability_report_table(methods: Mapping[str, GeneratorResult]) -> tuple[list[str], list[list[str]]]:
    """Per generator that ran: avoidable share at each reaction time, the collision rate split by the
    label, and the median last moment to act (``eval scenarios``' report)."""
    head = ["method", "variants", "avoidable @0.5 s", "avoidable @1 s", "avoidable @1.5 s", "CR avoidable",
            "CR unavoidable", "last moment to act, median [s]", "labels moved by reacting traffic"]
    rows = []
    for name, m in methods.items():
        a = m.avoidability
        if not a.variants:
            continue
        sh = a.avoidable_share
        rows.append([name, str(a.variants), *(_pct_of(sh[t]) if t in sh else "n/a" for t in ("0.5", "1", "1.5")),
                     _pct_of(a.CR_avoidable), _pct_of(a.CR_unavoidable),
                     str(a.last_moment_percentiles.get("p50", "n/a")), a.moved_cell()])
    return head, rows


def regression_table(summary: RegressionSummary) -> tuple[list[str], list[list[str]]]:
    head = ["planner", "runs", "failed", "RCR", "CR", "ORR", "adversary contact", "median min TTC [s]",
            "mean rel. speed [m/s]"]
    rows = []
    for name, p in summary.planners.items():
        rows.append([name, str(p.runs), str(p.failed), _pct(p.RCR), _pct(p.CR), _pct(p.ORR),
                     _pct(p.adversary_contact_rate), _fmt(p.median_min_ttc_s, 2), _fmt(p.mean_relative_speed_mps, 2)])
    return head, rows


def _defect_words(summary: RegressionSummary) -> str:
    return (f"{summary.avoidable_variants} of {summary.variants} variants were avoidable "
            "(an escape proven in SUMO from the stated reaction time after the adversary became a threat, "
            "docs/method.md step 8). A contact in an avoidable variant is a defect of the planner; a contact "
            "in an unavoidable one is not. Brackets: Wilson 95% interval (k/n runs)." + summary.moved_words())


def defect_section_md(summary: RegressionSummary, head: list[str], rows: list[list[str]]) -> list[str]:
    """The headline of a regression: defects (contact in an avoidable variant) apart from unavoidable contacts."""
    if not rows:
        return []
    return ["## Defects", "", _defect_words(summary), "", _md_table(head, rows), ""]


def defect_section_html(summary: RegressionSummary, head: list[str], rows: list[list[str]]) -> list[str]:
    """:func:`defect_section_md` in HTML, in the same words."""
    if not rows:
        return []
    return ["<h2>Defects</h2>", f"<p>{html.escape(_defect_words(summary))}</p>", _html_table(head, rows)]


def _md_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _html_table(head: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><thead><tr>{th}</tr></thead><tbody>{body}</tbody></table>"


def plot_rates(path: Path, summary: RegressionSummary) -> Path:
    """Grouped bars of RCR / CR / ORR per planner with Wilson 95 % error bars."""
    plt = _plt()
    planners = list(summary.planners)
    metrics = ["RCR", "CR", "ORR"]
    fig, ax = plt.subplots(figsize=(max(5.0, 1.8 * len(planners) + 2), 4))
    w = 0.8 / len(metrics)
    for j, m in enumerate(metrics):
        values = [getattr(summary.planners[p], m) for p in planners]
        rate = np.array([v.value or 0.0 for v in values], float)
        lo = np.array([v.ci_low or 0.0 for v in values], float)
        hi = np.array([v.ci_high or 0.0 for v in values], float)
        x = np.arange(len(planners)) + (j - 1) * w
        ax.bar(x, rate, w, label=m, yerr=np.clip(np.stack([rate - lo, hi - rate]), 0, None), capsize=3)
    ax.set_xticks(np.arange(len(planners)), planners)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel("rate (Wilson 95% CI)")
    _legend(ax)
    ax.set_title("route completion, collision and off-road rates per planner")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_contacts(angles_path: Path, speeds_path: Path, rows: Sequence[ResultRow],
                  planners: Sequence[str]) -> tuple[Path, Path]:
    """Impact-angle histogram (polar) and relative-speed histogram of first contacts, per planner."""
    plt = _plt()
    fig = plt.figure(figsize=(6, 6))
    ax = fig.add_subplot(projection="polar")
    bins = np.radians(np.linspace(-180, 180, 25))
    for p in planners:
        a = [r.impact_angle for r in rows if r.planner == p and r.impact_angle is not None]
        if a:
            h, _ = np.histogram(np.radians(a), bins=bins)
            ax.bar(bins[:-1] + 0.5 * np.diff(bins), h, width=np.diff(bins), alpha=0.45, edgecolor="black",
                   lw=0.5, label=f"{p} ({len(a)})")
    ax.set_theta_zero_location("E")
    ax.set_title("impact angle in the target frame (0 = ahead, 90 = left)", fontsize=10)
    _legend(ax, loc="lower left", fontsize=8, bbox_to_anchor=(-0.1, -0.15))
    fig.tight_layout()
    fig.savefig(angles_path, dpi=110)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 4))
    speeds = {p: [r.relative_speed for r in rows if r.planner == p and r.relative_speed is not None]
              for p in planners}
    top = max([max(v) for v in speeds.values() if v] + [1.0])
    edges = np.linspace(0, top * 1.05, 21)
    for p, v in speeds.items():
        if v:
            ax.hist(v, bins=edges, histtype="step", lw=1.5, label=f"{p} ({len(v)})")
    ax.set_xlabel("relative speed at first contact [m/s]")
    ax.set_ylabel("runs")
    _legend(ax, fontsize=8)
    fig.tight_layout()
    fig.savefig(speeds_path, dpi=110)
    plt.close(fig)
    return angles_path, speeds_path


def failure_examples(rows: Sequence[ResultRow], planners: Sequence[str],
                     per_planner: int = EXAMPLES_PER_PLANNER) -> dict[str, list[ResultRow]]:
    """Per planner, up to ``per_planner`` finished runs that failed the test: collision first, then
    off-road, then route not completed (stable order by run key)."""
    out: dict[str, list[ResultRow]] = {}
    for p in planners:
        mine = sorted((r for r in rows if r.planner == p and r.ok), key=lambda r: r.run_key)

        def rank(r: ResultRow) -> int:
            return 0 if r.collision else 1 if r.target_off_road else 2 if not r.route_completed else 3

        out[p] = [r for r in sorted(mine, key=rank) if rank(r) < 3][:per_planner]
    return out


def render_example(path: Path, out: Path, row: ResultRow, cache: dict[str, Any]) -> Path | None:
    """The scene at t_col, the target's nominal (dashed) and driven path, the adversary's plan and contact."""
    from coster_sumo.batch.scene_plans import ScenePlans
    from coster_sumo.formats.scene_file import load_scene
    from coster_sumo.pipeline import viz

    plans_dir = out / "plans"
    key = row.scene_key
    if key not in cache:
        doc = ScenePlans.from_json(json.loads((plans_dir / f"{key}.json").read_text()))
        cache[key] = (doc, load_scene(plans_dir / doc.scene_file))
    doc, scene = cache[key]
    variant = doc.variant(row.variant)
    plan = variant.plan
    t = scene.tracks
    target = t.index_of(doc.target_id)
    tv = t.valid[target]
    adv_t = np.arange(plan.t_start, plan.t_col + 1e-9, 0.1)
    ax_, ay_, _, _ = plan.sample(adv_t)
    driven = np.asarray(json.loads(row.target_path or "[]"), float).reshape(-1, 2)
    t_col_step = int(np.argmin(np.abs(scene.timestamps - plan.t_col)))
    near = tv & (scene.timestamps >= plan.t_start - 1.0) & (scene.timestamps <= plan.t_col + 2.0)
    pts = np.concatenate([np.stack([ax_, ay_], 1), np.stack([t.x[target, near], t.y[target, near]], 1)])
    window = viz.window_around(pts, margin=20.0)
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6, 6))
    viz.draw_map(ax, scene.road_map, window)
    viz.draw_agents(ax, scene, t_col_step, {target: viz.TARGET_COLOR})
    ax.plot(t.x[target, tv], t.y[target, tv], "--", color=viz.TARGET_COLOR, lw=1.0, label="target nominal", zorder=3)
    if len(driven):
        ax.plot(driven[:, 0], driven[:, 1], color="#2ca02c", lw=1.6, label=f"target driven ({row.planner})",
                zorder=4)
    ax.plot(ax_, ay_, color=viz.ADVERSARY_COLOR, lw=1.5, label="adversary plan", zorder=4)
    escape = doc.escape(row.variant)
    if escape:  # the variant was avoidable: the escape proven in SUMO
        ax.plot(escape["x"], escape["y"], ":", color="#9467bd", lw=1.8, label="escape (proven in SUMO)", zorder=5)
    s = variant.snapshot.adversary
    viz.draw_box(ax, s, viz.ADVERSARY_COLOR, label="adversary at t_col")
    if row.contact_time is not None:
        cx, cy, _, _ = plan.sample(np.array([row.contact_time]))
        ax.plot(cx[0], cy[0], marker="*", ms=14, color="gold", mec="black", zorder=8, label="first contact")
    what = ("collision" if row.collision else "off-road" if row.target_off_road else "route not completed")
    ax.set_title(f"{row.run_key}\n{what}" + (f", {row.relative_speed:.1f} m/s, {row.impact_angle:.0f} deg"
                                            if row.relative_speed is not None else ""), fontsize=8)
    _legend(ax, loc="upper right", fontsize=7)
    ax.set_xlim(window[0], window[2])
    ax.set_ylim(window[1], window[3])
    ax.set_aspect("equal")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _render_examples(out: Path, examples: Mapping[str, Sequence[ResultRow]]
                     ) -> dict[str, list[tuple[ResultRow, str]]]:
    """Each planner's failure examples drawn into ``out/examples/``: per planner, (row, picture path
    relative to ``out``, or "(render failed: ...)")."""
    cache: dict[str, Any] = {}
    ex_files: dict[str, list[tuple[ResultRow, str]]] = {}
    for p, chosen in examples.items():
        for r in chosen:
            rel = f"examples/{r.run_key}.png"
            try:
                render_example(out / rel, out, r, cache)
            except Exception as exc:  # noqa: BLE001 - a missing render never fails the report
                rel = f"(render failed: {exc})"
            ex_files.setdefault(p, []).append((r, rel))
    return ex_files


def _example_caption(r: ResultRow) -> str:
    """What went wrong in a failure example's run, in words."""
    return (("collision" if r.collision else "off-road" if r.target_off_road else "route not completed")
            + (f" at {r.contact_time:.1f} s" if r.contact_time is not None else "")
            + (f"; {r.outcome}" if r.outcome else ""))


def write_regression_report(out: Path, summary: RegressionSummary, rows: Sequence[ResultRow]) -> list[str]:
    """report.md, report.html, plots/ and examples/ in ``out``; returns the written paths (relative)."""
    out = Path(out)
    planners = list(summary.planners)
    keys = {r.run_key for r in rows}
    rows = [r for r in rows if r.planner in planners and r.run_key in keys]
    (out / "plots").mkdir(exist_ok=True)
    (out / "examples").mkdir(exist_ok=True)
    written = ["report.md", "report.html"]
    plot_rates(out / "plots" / "rates.png", summary)
    ok_rows = [r for r in rows if r.ok]
    plot_contacts(out / "plots" / "impact_angles.png", out / "plots" / "relative_speeds.png", ok_rows, planners)
    written += ["plots/rates.png", "plots/impact_angles.png", "plots/relative_speeds.png"]
    ex_files = _render_examples(out, failure_examples(ok_rows, planners))
    written += [rel for chosen in ex_files.values() for _, rel in chosen if rel.startswith("examples/")]
    head, table = regression_table(summary)
    d_head, d_table = defect_table(summary)
    failures = summary.runs.failures
    sc = summary.scenes
    # the same words in both reports (the HTML one had dropped the definitions, captions and the
    # "no failure" line)
    intro = (f"{sc.generated} of {sc.total} scenes generated, {summary.variants} variants, "
             f"{summary.runs.recorded} of {summary.runs.expected} runs recorded ({summary.runs.failed} failed).")
    definitions = ("RCR: route completion rate; CR: collision rate (the target touches the adversary or anyone); "
                   "ORR: the target's off-road rate; median min TTC: over the runs where the adversary never "
                   "touched the target; mean rel. speed: at contact. Brackets: Wilson 95% interval. Failed runs "
                   "are not in the rates.")
    no_failure = "No collision, off-road or incomplete route."
    caption = _example_caption
    md = ["# Planner regression", "", *defect_section_md(summary, d_head, d_table), intro, "", definitions, "",
          _md_table(head, table), "", "![rates](plots/rates.png)", "",
          "## Contacts", "", "![impact angles](plots/impact_angles.png) ![relative speeds](plots/relative_speeds.png)",
          ""]
    if sc.failed:
        md += ["## Scenes without variants", "", _md_table(["scene", "reason"],
                                                            [[f.scene, str(f.reason)] for f in sc.failed]), ""]
    if failures:
        md += ["## Failed runs", "", _md_table(["run", "reason"], [[f.run_key, str(f.reason)] for f in failures]), ""]
    md += ["## Failure examples", ""]
    for p in planners:
        md.append(f"### {p}")
        md.append("")
        if not ex_files.get(p):
            md += [no_failure, ""]
        for r, rel in ex_files.get(p, []):
            md.append(f"- `{r.run_key}`: " + caption(r))
            if rel.startswith("examples/"):
                md.append(f"\n  ![{r.run_key}]({rel})")
        md.append("")
    write_text(out / "report.md", "\n".join(md) + "\n")
    h = ["<!doctype html><html><head><meta charset='utf-8'><title>coster-sumo regression</title>",
         "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse}"
         "td,th{border:1px solid #ccc;padding:3px 8px;font-size:13px}img{max-width:48%}</style></head><body>",
         "<h1>Planner regression</h1>", *defect_section_html(summary, d_head, d_table),
         f"<p>{html.escape(intro)}</p>", f"<p>{html.escape(definitions)}</p>",
         _html_table(head, table), "<p><img src='plots/rates.png'></p>", "<h2>Contacts</h2>",
         "<p><img src='plots/impact_angles.png'> <img src='plots/relative_speeds.png'></p>"]
    if sc.failed:
        h += ["<h2>Scenes without variants</h2>",
              _html_table(["scene", "reason"], [[f.scene, str(f.reason)] for f in sc.failed])]
    if failures:
        h += ["<h2>Failed runs</h2>", _html_table(["run", "reason"], [[f.run_key, str(f.reason)] for f in failures])]
    h.append("<h2>Failure examples</h2>")
    for p in planners:
        h.append(f"<h3>{html.escape(p)}</h3>")
        if not ex_files.get(p):
            h.append(f"<p>{html.escape(no_failure)}</p>")
        for r, rel in ex_files.get(p, []):
            h.append(f"<figure><figcaption><code>{html.escape(r.run_key)}</code>: {html.escape(caption(r))}"
                     "</figcaption>" + (f"<img src='{html.escape(rel)}'>" if rel.startswith("examples/") else "")
                     + "</figure>")
    h.append("</body></html>")
    write_text(out / "report.html", "\n".join(h) + "\n")
    return written


# ============================================================================ generator evaluation

GENERATOR_COLUMNS = ("SUR", "CR", "ORR", "VDD", "ADD", "CSD", "CPD", "CPD_circular")


def _vdd_tcol(m: GeneratorResult) -> str:
    """VDD at t_col with, in brackets, the floor its sample size allows."""
    floor = m.VDD_tcol_floor
    return _fmt(m.VDD_tcol, 3) + (f" ({floor:.3f})" if floor is not None else "")


def generator_table(summary: EvalSummary) -> tuple[list[str], list[list[str]]]:
    head = ["method", "group", "scenes", "variants", "SUR", "CR", "ORR", "VDD", "ADD", "CSD [m/s]", "CPD [deg]",
            "CPD circ. [deg]", "VDD at t_col (floor)", "sizes in class", "gen. s/variant"]
    rows = []
    for name, m in summary.methods.table.items():
        if isinstance(m, SkippedGenerator):
            rows.append([name, m.method.group, "-", "-"] + [f"skipped: {m.reason}"] + [""] * (len(head) - 5))
            continue
        rows.append([name, m.method.group, str(m.scenes), str(m.variants),
                     *[_fmt(v, 3) for v in (m.SUR.value, m.CR.value, m.ORR.value, m.VDD, m.ADD)],
                     _fmt(m.CSD.value, 2), _fmt(m.CPD.value, 1), _fmt(m.CPD_circular.value, 1),
                     _vdd_tcol(m), _fmt(m.size_in_class, 3), _fmt(m.generation_s_per_variant, 3)])
    return head, rows


def _columns(m: GeneratorResult) -> dict[str, MetricValue]:
    """The figures of :data:`GENERATOR_COLUMNS` (VDD and ADD without an interval)."""
    return {"SUR": m.SUR, "CR": m.CR, "ORR": m.ORR, "VDD": MetricValue(m.VDD), "ADD": MetricValue(m.ADD),
            "CSD": m.CSD, "CPD": m.CPD, "CPD_circular": m.CPD_circular}


def plot_generator_metrics(path: Path, summary: EvalSummary) -> Path:
    """One small bar chart per metric, the methods that ran side by side."""
    plt = _plt()
    table = {k: _columns(m) for k, m in summary.methods.ran.items()}
    fig, axes = plt.subplots(2, 4, figsize=(14, 6))
    names = list(table)
    for ax, col in zip(axes.ravel(), GENERATOR_COLUMNS, strict=True):
        figures = [table[n][col] for n in names]
        vals = np.array([v.value if v.value is not None else np.nan for v in figures], float)
        # rates carry Wilson intervals, CSD and CPD intervals from resampling scenes
        ci = np.array([[v.ci_low, v.ci_high] for v in figures], float)
        err = np.abs(ci - vals[:, None]).T if np.isfinite(ci).any() else None
        ax.bar(np.arange(len(names)), vals, color=[f"C{i}" for i in range(len(names))], yerr=err, capsize=3)
        ax.set_xticks(np.arange(len(names)), names, rotation=35, ha="right", fontsize=7)
        ax.set_title(col, fontsize=10)
    skipped = [k for k, m in summary.methods.table.items() if isinstance(m, SkippedGenerator)]
    fig.suptitle("scenario generators" + (f" (skipped: {', '.join(skipped)})" if skipped else ""), fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def _with_ci(v: MetricValue | tuple[float, float, float], digits: int) -> str:
    """A figure and its interval, or the figure alone where the interval is missing or not finite."""
    value, low, high = (v.value, v.ci_low, v.ci_high) if isinstance(v, MetricValue) else v
    if value is None or low is None or high is None or not all(math.isfinite(c) for c in (low, high)):
        return _fmt(value, digits)
    return f"{value:.{digits}f} [{low:.{digits}f}, {high:.{digits}f}]"


def _diversity_cells(csd: MetricValue | tuple[float, float, float], cpd: MetricValue | tuple[float, float, float],
                     cpd_circular: MetricValue | tuple[float, float, float]) -> list[str]:
    """CSD [m/s] to 2 digits, CPD and circular CPD [deg] to 1, each with its interval."""
    return [_with_ci(csd, 2), _with_ci(cpd, 1), _with_ci(cpd_circular, 1)]


def diversity_section(summary: EvalSummary) -> list[str]:
    """Markdown lines: CSD and CPD with 95 % intervals from resampling scenes, and COSTER's minus
    every other method's on the same scenes (empty when there is nothing to show)."""
    table = summary.methods.ran
    if not table:
        return []
    head = ["method", "CSD [m/s]", "CPD [deg]", "CPD circ. [deg]"]
    rows = [[name, *_diversity_cells(m.CSD, m.CPD, m.CPD_circular)] for name, m in table.items()]
    md = ["## Diversity: how sure", "",
          "In brackets the 95 % interval from resampling the scenes (1,000 draws; the variants of a scene "
          "share its snapshot, so a scene is one draw).", "", _md_table(head, rows), ""]
    paired = summary.methods.paired
    if paired:
        prow = [[name, str(e.scenes), *_diversity_cells(e.CSD, e.CPD, e.CPD_circular)] for name, e in paired.items()]
        md += ["The differences on the scenes both methods generated for, the same scenes resampled for both: "
               "an interval that holds 0 says the ordering is not settled by these scenes.", "",
               _md_table(["difference", "scenes", "CSD [m/s]", "CPD [deg]", "CPD circ. [deg]"], prow), ""]
    return md


def write_generator_report(out: Path, summary: EvalSummary) -> list[str]:
    """metrics.json, metrics.md and metrics.png in ``out``; returns the written paths (relative)."""
    out = Path(out)
    methods = summary.methods
    doc = {"methods": {k: m.to_json(contacts=False) for k, m in methods.table.items()},
           "paired": {k: p.to_json() for k, p in methods.paired.items()},
           "failed_scenes": [f.to_json() for f in methods.failed_scenes], "planner": summary.planner,
           "variants": summary.variants, "units": dict(summary.units)}
    write_text(out / "metrics.json", json.dumps(doc, indent=1))
    plot_generator_metrics(out / "metrics.png", summary)
    head, rows = generator_table(summary)
    md = ["# Scenario generators", "",
          f"{len(summary.scenes)} scenes, up to {summary.variants} {summary.adversary} variants per scene and method, "
          f"target driven by `{summary.planner}`. Measured on these scenes with this installation; not the paper's "
          "figures.", "",
          "SUR: share of scenes with at least one colliding variant; CR: colliding variants; ORR: adversaries leaving "
          "the road (a VRU: its class's area); VDD/ADD: Jensen-Shannon divergence (nats) of the adversaries' speed / "
          "acceleration histograms (10 Hz, plan start to contact) against every agent of the raw scenes (a VRU: its "
          "class's); CSD: std of the relative speed at contact; CPD: std of the impact angle (linear, circular); VDD "
          "at t_col: the same divergence between the adversaries' speeds at t_col and the nominal vehicles' (a VRU: "
          "its class's) on lanes of the same type (in brackets: its floor, what speeds drawn from the nominal traffic "
          "itself would score with as many adversaries); sizes in class: adversaries whose length and width fit one "
          "vehicle class of the corpus.", "",
          _md_table(head, rows), "", "![metrics](metrics.png)", "", *diversity_section(summary)]
    a_head, a_rows = avoidability_report_table(methods.ran)
    if a_rows:
        md += ["## Avoidability", "", "Share of variants the target could have avoided (an escape proven in SUMO "
               "acting that long after the adversary became a threat; docs/method.md step 8), Wilson 95% interval; "
               "the collision rate of each part (a contact in an avoidable variant is a planner's defect).", "",
               _md_table(a_head, a_rows), ""]
    if methods.failed_scenes:
        md += ["## Scenes that failed", "", _md_table(["scene", "reason"],
                                                       [[f.scene_key, str(f.reason)] for f in methods.failed_scenes]),
               ""]
    write_text(out / "metrics.md", "\n".join(md) + "\n")
    return ["metrics.json", "metrics.md", "metrics.png"]
