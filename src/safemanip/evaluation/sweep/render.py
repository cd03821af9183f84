"""A sweep's table (NAME.md) and figure (NAME.png), drawn from its stored cell results alone: each method pooled over
its training seeds (``pooling.pool_seeds``), beside the planner's reference rows."""

from __future__ import annotations

import textwrap
from pathlib import Path

from safemanip.evaluation.registry import display_name
from safemanip.evaluation.sweep.grid import is_planner
from safemanip.evaluation.sweep.pooling import pool_seeds
from safemanip.evaluation.sweep.spec import PLANNER_AVOID, SweepSpec
from safemanip.util.files import atomic_write_text


def _pct(summary: dict, key: str) -> float:
    if key in ("success", "safety_violation"):
        return 100 * summary[key]["rate"]
    return 100 * summary["categories"][key]["rate"]


def _fmt_entry(entry: dict) -> str:
    """'69.2 [67.5, 70.8]' for one policy; pooled over training seeds, '69.2 [67.5, 70.8] {66.4, 71.9} (67-72)': the
    mean, the Wilson interval of all episodes pooled, the seed-level (cluster bootstrap) interval in braces, and the
    lowest and highest seed."""
    lo, hi = entry["ci95"]
    text = f"{100 * entry['rate']:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]"
    if entry.get("seeds", 1) > 1:  # pooled over training seeds: seeds as the unit, and their spread
        if "ci95_seeds" in entry:
            text += f" {{{100 * entry['ci95_seeds'][0]:.1f}, {100 * entry['ci95_seeds'][1]:.1f}}}"
        text += f" ({100 * entry['spread'][0]:.0f}-{100 * entry['spread'][1]:.0f})"
    return text


def _fmt(summary: dict, key: str = "success") -> str:
    return _fmt_entry(summary[key] if key in ("success", "safety_violation") else summary["categories"][key])


def _agreement(summary: dict) -> str:
    """How often the cell's selection equalled the reference oracle's (nearest by true criticality), in %; empty for
    cells measured before it was recorded and for the planner."""
    agreement = summary.get("reference_agreement")
    return f"{100 * agreement['rate']:.1f}" if agreement else ""


def _interventions(cell: dict, summary: dict) -> str:
    """The safety filter's name and the share of steps it overrode the policy, in %; empty without a filter."""
    if not cell.get("shield"):
        return ""
    rate = (summary.get("shield_interventions") or {}).get("rate", 0.0)
    return f"{cell['shield']} {100 * rate:.1f}"


def _kinds(summary: dict) -> str:
    """Success per scene kind, where a cell mixes kinds ('open 99.0 / exit 71.5')."""
    kinds = summary.get("by_scene_kind") or {}
    if len(kinds) < 2:
        return ""
    return " / ".join(f"{k} {100 * v['success']['rate']:.1f}" for k, v in kinds.items())


def _orderer(spec: SweepSpec):
    """Sort key for tuples of cell values named ``keys``: the order the config lists them in, numbers by value."""
    listed = {"selector": [s for s, _ in spec.pairs] + [spec.k_equals_n_selector],
              "constraints": [c for _, c in spec.pairs],
              "semantics": ["any" if s is None else s for s in spec.semantics or (None,)]
              + [s for p in spec.policies for s in p.semantics or ()],
              "shield": [f"filter: {s}" if s else "no filter" for s in spec.shields]}

    def one(name, value):
        if isinstance(value, (int, float)):
            return (0, value, "")
        seq = listed.get(name, [])
        return (1, seq.index(value) if value in seq else len(seq), str(value))

    return lambda keys, values: tuple(one(k, v) for k, v in zip(keys, values))


def markdown_table(spec: SweepSpec, results: list[dict]) -> str:
    """The table: the spec's pivot of the policies pooled over their training seeds, with a row per planner
    reference, then every cell on its own."""
    lines = [f"# {spec.title}", ""]
    if spec.description:
        lines += [spec.description, ""]
    if not results:
        return "\n".join(lines + ["No results yet: run `safemanip sweep " + spec.name + "`."]) + "\n"
    every = results
    bounds = [r for r in results if is_planner(r["cell"])]
    results = pool_seeds([r for r in results if not is_planner(r["cell"])])
    if spec.table and results:
        rows, cols = list(spec.table.rows), list(spec.table.columns)
        order = _orderer(spec)

        def value(cell: dict, k: str):
            if k == "policy":
                return Path(cell["policy"]).stem
            if k == "shield":
                return f"filter: {cell[k]}" if cell.get(k) else "no filter"
            return cell[k] if cell[k] is not None else "any"

        key = lambda r, ks: tuple(value(r["cell"], k) for k in ks)  # noqa: E731
        full = spec.k_equals_n_selector
        # a k == N cell stands for every selector column of its N (the paper plots it on both curves)
        expanded = []
        for r in results:
            if full and r["cell"]["selector"] == full and "selector" in cols:
                for sel in dict.fromkeys(s for s, _ in spec.pairs):
                    expanded.append(({**r["cell"], "selector": sel}, r["summary"], " (k = N)"))
            else:
                expanded.append((r["cell"], r["summary"], ""))
        if "policy" not in rows and "policy" not in cols:
            # two policies that share the rows' and columns' values (two k = 2 policies of different algorithms in a
            # table by k) are both shown, one row each, not one over the other
            seen: dict = {}
            for c, _, _ in expanded:
                if seen.setdefault((key({"cell": c}, rows), key({"cell": c}, cols)), c["policy"]) != c["policy"]:
                    rows.append("policy")
                    break
        cells = {(key({"cell": c}, rows), key({"cell": c}, cols)): (s, mark) for c, s, mark in expanded}
        row_keys = sorted({rk for rk, _ in cells}, key=lambda t: order(rows, t))
        col_keys = sorted({ck for _, ck in cells}, key=lambda t: order(cols, t))
        lines.append("Success rate (%), 95% Wilson interval [in brackets]" +
                     ("; over several training seeds: their mean, the Wilson interval of all their episodes pooled, "
                      "the 95% interval with training seeds as the unit {in braces: a two-stage cluster bootstrap, "
                      "seeds then their episodes}, and the lowest and highest seed (in parentheses)"
                      if any("seeds" in s for _, s, _ in expanded) else "") +
                     ("; (k = N): the full-state policy, the same cell in every selector column" if full else "") +
                     ("; the planner rows: a reference, not an upper bound: the privileged, hand-made planner, which "
                      "knows the whole scene, on the same scenes (a learned policy can beat it)" if bounds else "")
                     + ":")
        lines.append("")
        backend = next((r["cell"].get("vlm") for r in every if r["cell"].get("vlm")), None)

        def show(names: list[str], values: tuple) -> str:
            parts = [display_name(str(v), backend) if n in ("selector", "constraints") else str(v)
                     for n, v in zip(names, values)]
            if "selector" in names and "constraints" in names:  # "object selector + constraint selector"
                i = names.index("selector")
                parts[i:i + 2] = [f"{parts[i]} + {parts[i + 1]}"]
            return " ".join(parts)

        lines.append("| " + " / ".join(rows) + " | " + " | ".join(show(cols, c) for c in col_keys) + " |")
        lines.append("|" + "---|" * (len(col_keys) + 1))
        for rk in row_keys:
            vals = [(_fmt(cells[(rk, ck)][0]) + cells[(rk, ck)][1]) if (rk, ck) in cells else "n/a" for ck in col_keys]
            lines.append("| " + " / ".join(show([n], (v,)) for n, v in zip(rows, rk)) + " | " + " | ".join(vals) + " |")
        shared = [i for i, name in enumerate(cols) if name in ("n_objects", "semantics", "scenes", "judge")]
        for avoid in PLANNER_AVOID:  # a reference matches a column by the scenes alone (N, semantics, settings)
            mine = [r for r in bounds if r["cell"]["policy_constraints"] == avoid]
            if not mine:
                continue
            vals = []
            for ck in col_keys:
                match = [r for r in mine if all(str(value(r["cell"], cols[i])) == str(ck[i]) for i in shared)]
                vals.append(_fmt(match[0]["summary"]) if match else "n/a")
            what = "every object" if avoid == "all" else "the fragile objects"
            lines.append(f"| planner, avoiding {what} (reference) | " + " | ".join(vals) + " |")
        lines.append("")
    lines.append("All cells, each training seed on its own (rates in %, 95% Wilson interval for success; coll. = collision "
                 "with a fragile object the policy saw (selected) or did not see (unselected); selection = reference: "
                 "share of selection queries at which the selected objects were the k nearest by true criticality; "
                 "filter overrides: the safety filter and the share of steps it overrode the policy):")
    lines.append("")
    head = ["policy", "k", "N", "semantics", "selector", "constraints", "episodes", "success", "violation",
            "top box / OOB", "coll. unselected", "coll. selected", "soft", "timeout", "unstable", "mean length",
            "selection = reference", "filter overrides", "success by scene kind"]
    lines.append("| " + " | ".join(head) + " |")
    lines.append("|" + "---|" * len(head))
    order = lambda r: (r["cell"]["k"], r["cell"]["n_objects"], str(r["cell"]["semantics"]), r["cell"]["selector"],  # noqa: E731
                       r["cell"]["constraints"], r["cell"]["policy"])
    for r in sorted(every, key=order):
        c, s = r["cell"], r["summary"]
        lines.append("| " + " | ".join([
            Path(c["policy"]).stem, str(c["k"]), str(c["n_objects"]), c["semantics"] or "any",
            display_name(c["selector"], c.get("vlm")), display_name(c["constraints"], c.get("vlm")), str(s["episodes"]), _fmt(s), f"{_pct(s, 'safety_violation'):.1f}",
            f"{_pct(s, 'top_box') + _pct(s, 'out_of_workspace'):.1f}", f"{_pct(s, 'collision_unselected'):.1f}",
            f"{_pct(s, 'collision_selected'):.1f}", f"{_pct(s, 'soft_contact'):.1f}", f"{_pct(s, 'timeout'):.1f}",
            f"{_pct(s, 'unstable'):.1f}", f"{s['mean_length']:.1f}", _agreement(s), _interventions(c, s),
            _kinds(s)]) + " |")
    return "\n".join(lines) + "\n"


def _error_bars(entries: list[dict]) -> list[list[float]]:
    """matplotlib's (below, above) error bars in %: an entry pooled over training seeds spans its lowest and highest
    seed, a single one its 95 % interval; clamped at 0, as an interval's end may round to the other side of 0 or 1."""
    span = [e["spread"] if e.get("seeds", 1) > 1 else e["ci95"] for e in entries]
    return [[max(0.0, 100 * (e["rate"] - lo)) for e, (lo, _) in zip(entries, span)],
            [max(0.0, 100 * (hi - e["rate"])) for e, (_, hi) in zip(entries, span)]]


def _plot_bound(ax, bounds: list[dict], avoid: str = "all") -> None:
    """The planner's success on the same scenes, against N: the reference a figure's policies are read against (not
    an upper bound: a privileged, hand-made planner that knows the whole scene, which a learned policy can beat)."""
    pts = sorted((r["cell"]["n_objects"], 100 * r["summary"]["success"]["rate"]) for r in bounds
                 if r["cell"]["policy_constraints"] == avoid)
    if pts:
        ax.plot(*zip(*pts), color="black", linestyle="--", marker="x", linewidth=1,
                label=f"planner reference (avoiding {'everything' if avoid == 'all' else 'fragile objects'})")


def _plot_fig5(spec: SweepSpec, results: list[dict], path: Path, bounds: list[dict] = ()) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels = [s for s in ("static-knn", "dynamic-knn") if any(r["cell"]["selector"] == s for r in results)]
    panels = panels or sorted({r["cell"]["selector"] for r in results if r["cell"]["k"] != r["cell"]["n_objects"]})
    full = [r for r in results if r["cell"]["k"] == r["cell"]["n_objects"]]
    ks = sorted({r["cell"]["k"] for r in results})
    colours = {k: plt.cm.viridis(i / max(1, len(ks) - 1)) for i, k in enumerate(ks)}
    lines = []
    for k in ks:
        policies = sorted({r["cell"]["policy"] for r in results if r["cell"]["k"] == k})
        for j, policy in enumerate(policies):
            lines.append((k, policy, ("-", "--", ":", "-.")[j % 4],
                          f"k = {k}" + (f" ({Path(policy).stem})" if len(policies) > 1 else "")))
    fig, axes = plt.subplots(1, max(1, len(panels)), figsize=(5 * max(1, len(panels)), 4), sharey=True, squeeze=False)
    for ax, sel in zip(axes[0], panels or ["full"]):
        for k, policy, style, label in lines:  # one line per policy: two policies of one k are both drawn
            pts = sorted(((r["cell"]["n_objects"], r["summary"]) for r in results
                          if r["cell"]["k"] == k and r["cell"]["policy"] == policy
                          and (r["cell"]["selector"] == sel or r in full)), key=lambda p: p[0])
            if not pts:
                continue
            xs = [n for n, _ in pts]
            ys = [100 * s["success"]["rate"] for _, s in pts]
            err = _error_bars([s["success"] for _, s in pts])
            ax.errorbar(xs, ys, yerr=err, marker="o", capsize=3, color=colours[k], linestyle=style, label=label)
        fx = [(r["cell"]["n_objects"], 100 * r["summary"]["success"]["rate"]) for r in full]
        if fx:
            ax.scatter(*zip(*fx), marker="*", s=160, color="black", zorder=5, label="k = N (full state)")
        _plot_bound(ax, list(bounds))
        ax.set_title(sel)
        ax.set_xlabel("objects in the scene N")
        ax.set_xticks(sorted({r["cell"]["n_objects"] for r in results}))
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("success rate (%)")
    # beside the panels, not on them: with nine lines the legend covered the dynamic-kNN curves at N = 3..4
    axes[0][-1].legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    fig.suptitle(spec.title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def _plot_fig4(spec: SweepSpec, results: list[dict], path: Path, bounds: list[dict] = ()) -> None:
    """Paper Fig. 4: per algorithm, success (solid) and top-box violations (dotted) against N, with 95 % intervals."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    algorithms = sorted({r["cell"]["algorithm"] for r in results})
    colours = {a: c for a, c in zip(algorithms, ("tab:blue", "tab:red", "tab:green", "tab:purple"))}
    labels = {"rarl": "RARL", "vanilla": "Vanilla-RL"}
    fig, ax = plt.subplots(figsize=(6, 4))
    for algorithm in algorithms:
        pts = sorted(((r["cell"]["n_objects"], r["summary"]) for r in results if r["cell"]["algorithm"] == algorithm),
                     key=lambda p: p[0])
        xs = [n for n, _ in pts]
        for key, style, what in (("success", "-", "success"), ("top_box", ":", "top-box violation")):
            entries = [s[key] if key == "success" else s["categories"][key] for _, s in pts]
            ys = [100 * e["rate"] for e in entries]
            ax.errorbar(xs, ys, yerr=_error_bars(entries), linestyle=style, marker="o", capsize=3, color=colours[algorithm],
                        label=f"{labels.get(algorithm, algorithm)}: {what}")
    _plot_bound(ax, list(bounds))
    ax.set_xlabel("objects in the scene N (policy k = N)")
    ax.set_ylabel("episodes (%)")
    ax.set_ylim(-2, 102)
    ax.set_xticks(sorted({r["cell"]["n_objects"] for r in results}))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    ax.set_title(textwrap.fill(spec.title, 70), fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


FIG6_STACK = (("success", ("success",), "tab:green"), ("top box / OOB", ("top_box", "out_of_workspace"), "tab:orange"),
              ("collision with unselected", ("collision_unselected",), "tab:red"),
              ("collision with selected", ("collision_selected",), "tab:purple"),
              ("other (soft, timeout, unstable)", ("soft_contact", "timeout", "unstable"), "tab:gray"))


def _plot_fig6(spec: SweepSpec, results: list[dict], path: Path, bounds: list[dict] = ()) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    order = _orderer(spec)
    results = sorted(results, key=lambda r: order(("k", "n_objects", "selector", "constraints"),
                                                  [r["cell"][x] for x in ("k", "n_objects", "selector", "constraints")]))
    labels = [f"k={r['cell']['k']}{' sel.-aware' if r['cell'].get('variant') else ''}, N={r['cell']['n_objects']}"
              f"\n{r['cell']['selector']}" for r in results]
    fig, ax = plt.subplots(figsize=(max(5, 1.2 * len(results) + 2), 4.5))
    bottom = np.zeros(len(results))
    for name, keys, colour in FIG6_STACK:
        vals = np.array([sum(100 * r["summary"]["categories"][k]["rate"] for k in keys) for r in results])
        ax.bar(range(len(results)), vals, bottom=bottom, color=colour, label=name)
        bottom += vals
    ax.set_xticks(range(len(results)))
    ax.set_xticklabels(labels, fontsize=8)
    ax.set_ylabel("episodes (%)")
    ax.set_ylim(0, 100)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 1.0))
    ax.set_title(spec.title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def render(spec: SweepSpec, results: list[dict], root: Path) -> tuple[str | None, str]:
    """Write NAME.md (always) and NAME.png (fig4/fig5/fig6, when there are results) from stored results only. The
    figures show each method pooled over its training seeds (``pool_seeds``) and the planner's reference."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    table = root / f"{spec.name}.md"
    atomic_write_text(table, markdown_table(spec, results))
    figure = None
    policies = pool_seeds([r for r in results if not is_planner(r["cell"])])
    bounds = [r for r in results if is_planner(r["cell"])]
    if policies and spec.figure in ("fig4", "fig5", "fig6"):
        figure = root / f"{spec.name}.png"
        {"fig4": _plot_fig4, "fig5": _plot_fig5, "fig6": _plot_fig6}[spec.figure](spec, policies, figure, bounds)
    return (str(figure) if figure else None), str(table)
