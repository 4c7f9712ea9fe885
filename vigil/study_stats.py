"""The statistics of a Monte-Carlo study (:mod:`vigil.montecarlo`): the summary with its
95 % intervals, the Markdown table, the worst episodes and the figure.

Intervals: proportions (guarded, robot first, episodes with a false trip) are
binomial (Wilson score interval); means (delay, trips per episode, warning lead) are
bootstrapped over episodes (2000 resamples, seeded), because the visits of one episode
are not independent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from stack.files import save_figure

Z95 = 1.959963984540054
BOOTSTRAP = 2000


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float | None, float | None]:
    """The Wilson score interval of a binomial proportion (None, None when n == 0)."""
    if n <= 0:
        return None, None
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def bootstrap_mean(
    groups: Sequence[Sequence[float]], seed: int = 0, n: int = BOOTSTRAP
) -> tuple[float | None, float | None, float | None]:
    """Mean of all values and its 95 % percentile interval, resampling whole groups
    (episodes) with replacement. (None, None, None) without values."""
    flat = [v for g in groups for v in g]
    if not flat:
        return None, None, None
    rng = np.random.default_rng(seed)
    sums = np.array([sum(g) for g in groups], float)
    counts = np.array([len(g) for g in groups], float)
    idx = rng.integers(0, len(groups), size=(n, len(groups)))
    s, c = sums[idx].sum(axis=1), counts[idx].sum(axis=1)
    means = s[c > 0] / c[c > 0]
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(np.mean(flat)), float(lo), float(hi)


def summarise(episodes: Sequence[dict[str, Any]], seed: int = 0) -> dict[str, Any]:
    """The study's summary (deterministic for the same episodes)."""
    ok = [e for e in episodes if "error" not in e]
    visits = sum(e["n_visits"] for e in ok)
    guarded = sum(e["guarded"] for e in ok)
    reachable = sum(e.get("reachable", 0) for e in ok)
    guarded_reachable = sum(e.get("guarded_reachable", 0) for e in ok)
    q_lo, q_hi = wilson(guarded_reachable, reachable)
    # several people: the visits one ideal guard could guard (vigil.report.people); a
    # one-person episode's are its reachable visits
    several = any(e.get("one_guard") is not None for e in ok)
    one_guard = sum(
        e["one_guard"] if e.get("one_guard") is not None else e.get("reachable", 0) for e in ok
    )
    o_lo, o_hi = wilson(min(guarded_reachable, one_guard), one_guard)
    with_trip = sum(e["n_false_trips"] > 0 for e in ok)
    d_mean, d_lo, d_hi = bootstrap_mean([e["delays_s"] for e in ok], seed)
    t_mean, t_lo, t_hi = bootstrap_mean([[e["n_false_trips"]] for e in ok], seed + 1)
    r_lo, r_hi = wilson(guarded, visits)
    e_lo, e_hi = wilson(with_trip, len(ok))
    first = sum(e.get("robot_first", 0) for e in ok)
    f_lo, f_hi = wilson(first, visits)
    n_mean, n_lo, n_hi = bootstrap_mean([[e.get("n_needless_trips", 0)] for e in ok], seed + 2)
    l_mean, l_lo, l_hi = bootstrap_mean([e.get("warning_leads_s", []) for e in ok], seed + 3)

    def r(x: float | None, nd: int = 3) -> float | None:
        return None if x is None else round(x, nd)

    return {
        "episodes": len(episodes),
        "failed_episodes": len(episodes) - len(ok),
        "visits": visits,
        "guarded": guarded,
        "abandoned": sum(e["abandoned"] for e in ok),
        "guarded_rate": r(guarded / visits) if visits else None,
        "guarded_rate_ci95": [r(r_lo), r(r_hi)],
        "reachable": reachable,
        "guarded_reachable": guarded_reachable,
        "guarded_reachable_rate": r(guarded_reachable / reachable) if reachable else None,
        "guarded_reachable_rate_ci95": [r(q_lo), r(q_hi)],
        **(
            {
                "one_guard": one_guard,
                "guarded_one_guard_rate": r(guarded_reachable / one_guard) if one_guard else None,
                "guarded_one_guard_rate_ci95": [r(o_lo), r(o_hi)],
            }
            if several
            else {}
        ),
        "mean_delay_s": r(d_mean, 2),
        "mean_delay_ci95_s": [r(d_lo, 2), r(d_hi, 2)],
        "max_delay_s": r(max((d for e in ok for d in e["delays_s"]), default=None), 2),
        "false_trips": sum(e["n_false_trips"] for e in ok),
        "false_trips_per_episode": r(t_mean),
        "false_trips_per_episode_ci95": [r(t_lo), r(t_hi)],
        "episodes_with_false_trip": with_trip,
        "episodes_with_false_trip_ci95": [r(e_lo), r(e_hi)],
        "episodes_with_fault": sum(bool(e["faults"]) for e in episodes),
        "robot_first": first,
        "robot_first_rate": r(first / visits) if visits else None,
        "robot_first_rate_ci95": [r(f_lo), r(f_hi)],
        "needless_trips": sum(e.get("n_needless_trips", 0) for e in ok),
        "needless_trips_per_episode": r(n_mean),
        "needless_trips_per_episode_ci95": [r(n_lo), r(n_hi)],
        "mean_warning_lead_s": r(l_mean, 2),
        "mean_warning_lead_ci95_s": [r(l_lo, 2), r(l_hi, 2)],
        "timely_warnings": sum(e["timely_warnings"] for e in ok),
        "late_warnings": sum(e["late_warnings"] for e in ok),
        "approach_warnings": sum(e.get("approach_warnings", 0) for e in ok),
        "sim_s": round(sum(e.get("sim_s", 0.0) for e in ok), 1),
        "wall_s_per_episode": r(float(np.mean([e.get("wall_s", 0.0) for e in ok])), 2)
        if ok
        else None,
    }


def worst_episodes(episodes: Sequence[dict[str, Any]], n: int = 5) -> list[dict[str, Any]]:
    """The ``n`` episodes a reader should look at first: failed ones, then by reachable
    visits missed, needless and false trips, late warnings, and the longest delay."""

    def badness(e: dict[str, Any]) -> tuple:
        if "error" in e:
            return (1, 0, 0, 0, 0.0)
        missed = e.get("reachable", 0) - e.get("guarded_reachable", 0)
        trips = e.get("n_needless_trips", 0) + e["n_false_trips"]
        return (0, missed, trips, e["late_warnings"], max(e["delays_s"], default=0.0))

    ranked = sorted(episodes, key=badness, reverse=True)
    return [e for e in ranked[:n] if badness(e) > (0, 0, 0, 0, 0.0)]


def _ci(v: Sequence[float | None], fmt: str) -> str:
    return "-" if v[0] is None else f"[{fmt.format(v[0])}, {fmt.format(v[1])}]"


def _num(v: float | None, unit: str = "") -> str:
    return "-" if v is None else f"{v:.1f}{unit}"


def _pct(v: float | None) -> str:
    return "-" if v is None else f"{100 * v:.0f} %"


def _pct_ci(v: Sequence[float | None] | None) -> str:
    return "-" if not v or v[0] is None else f"[{_pct(v[0])}, {_pct(v[1])}]"


def summary_markdown(s: dict[str, Any], title: str) -> str:
    """The summary as a Markdown table."""
    rate = "-" if s["guarded_rate"] is None else f"{100 * s['guarded_rate']:.0f} %"
    rate_ci = "-" if s["guarded_rate_ci95"][0] is None else (
        f"[{100 * s['guarded_rate_ci95'][0]:.0f} %, {100 * s['guarded_rate_ci95'][1]:.0f} %]"
    )  # fmt: skip
    delay = "-" if s["mean_delay_s"] is None else f"{s['mean_delay_s']:.1f} s"
    trips_ep = f"{s['episodes_with_false_trip']} / {s['episodes'] - s['failed_episodes']}"
    lines = [
        f"### {title}",
        "",
        "| metric | value | 95 % CI | basis |",
        "|---|---|---|---|",
        f"| guarded-visit rate | {rate} | {rate_ci} | {s['guarded']} of {s['visits']} "
        "visits (Wilson) |",
        f"| reachable visits guarded | {_pct(s.get('guarded_reachable_rate'))} | "
        f"{_pct_ci(s.get('guarded_reachable_rate_ci95'))} | {s.get('guarded_reachable')} of "
        f"{s.get('reachable')} visits an ideal guard at 0.5 m/s could reach (Wilson) |",
        *(
            [
                f"| of what one guard could guard | {_pct(s.get('guarded_one_guard_rate'))} | "
                f"{_pct_ci(s.get('guarded_one_guard_rate_ci95'))} | {s.get('guarded_reachable')} "
                f"of the {s['one_guard']} reachable visits one ideal guard could be in, one "
                "after the other (Wilson) |"
            ]
            if "one_guard" in s
            else []
        ),
        f"| mean delay | {delay} | {_ci(s['mean_delay_ci95_s'], '{:.1f} s')} | guarded "
        f"visits, bootstrap over episodes; max {s['max_delay_s']} s |",
        f"| false trips per episode | {s['false_trips_per_episode']} | "
        f"{_ci(s['false_trips_per_episode_ci95'], '{:.2f}')} | {s['false_trips']} trips "
        "(bootstrap) |",
        f"| episodes with a false trip | {trips_ep} | "
        f"{_ci(s['episodes_with_false_trip_ci95'], '{:.2f}')} | Wilson |",
        f"| robot in the cell first | {_pct(s.get('robot_first_rate'))} | "
        f"{_pct_ci(s.get('robot_first_rate_ci95'))} | {s.get('robot_first')} of "
        f"{s['visits']} visits (Wilson) |",
        f"| needless trips per episode | {s.get('needless_trips_per_episode')} | "
        f"{_ci(s.get('needless_trips_per_episode_ci95') or [None], '{:.2f}')} | "
        f"{s.get('needless_trips')} trips into a restricted cell nobody was in within 10 s "
        "(bootstrap) |",
        f"| mean warning lead | {_num(s.get('mean_warning_lead_s'), ' s')} | "
        f"{_ci(s.get('mean_warning_lead_ci95_s') or [None], '{:.1f} s')} | first warning "
        "before (> 0) or after (< 0) the entry (bootstrap) |",
        f"| visits abandoned | {s['abandoned']} | | |",
        f"| warnings timely / late | {s['timely_warnings']} / {s['late_warnings']} | | "
        f"{s['approach_warnings']} of the timely to a person next to the guarded cell |",
        f"| episodes with a sensor outage | {s['episodes_with_fault']} | | |",
        f"| failed episodes | {s['failed_episodes']} | | |",
        "",
    ]
    return "\n".join(lines)


def plot_study(path: Path, episodes: Sequence[dict[str, Any]], s: dict[str, Any], title: str):
    """Per episode: visits guarded / not guarded, false trips, outages (left); the
    delays with their mean and 95 % interval (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    ok = [e for e in episodes if "error" not in e]
    x = np.arange(len(ok))
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(12, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    g = np.array([e["guarded"] for e in ok])
    v = np.array([e["n_visits"] for e in ok])
    a1.bar(x - 0.2, g, 0.4, color="g", label="visits guarded")
    a1.bar(x - 0.2, v - g, 0.4, bottom=g, color="r", label="visits not guarded")
    a1.bar(x + 0.2, [e["n_false_trips"] for e in ok], 0.4, color="m", label="false trips")
    labels = [
        e["episode"].split("-")[-1] + ("\n" + e["faults"][0]["kind"][0] if e["faults"] else "")
        for e in ok
    ]
    a1.set_xticks(x, labels, fontsize=7)
    a1.set_xlabel("episode (c / l: camera / lidar outage)")
    a1.set_ylabel("count")
    a1.yaxis.set_major_locator(MaxNLocator(integer=True))
    a1.legend(fontsize=7)
    a1.grid(alpha=0.2, axis="y")
    delays = [d for e in ok for d in e["delays_s"]]
    if delays:
        a2.hist(delays, bins=min(12, max(3, len(delays))), color="steelblue")
        if s["mean_delay_s"] is not None:
            a2.axvline(s["mean_delay_s"], color="k", label=f"mean {s['mean_delay_s']:.1f} s")
            lo, hi = s["mean_delay_ci95_s"]
            a2.axvspan(lo, hi, color="k", alpha=0.15, label="95 % CI of the mean")
        a2.legend(fontsize=7)
    a2.set_xlabel("delay: robot in the cell after the person entered [s]")
    a2.set_ylabel("visits")
    rate = s["guarded_rate"]
    fig.suptitle(
        f"{title}: guarded {s['guarded']}/{s['visits']}"
        + (f" ({100 * rate:.0f} %)" if rate is not None else "")
        + f", false trips {s['false_trips']} in {len(ok)} episodes",
        fontsize=10,
    )
    fig.tight_layout()
    save_figure(fig, path, dpi=110, metadata={"Software": None})
    plt.close(fig)
    return path


# -- two studies of the same walks ----------------------------------------------------------------


def _visit_key(v: dict[str, Any]) -> tuple[int, float]:
    return int(v["cell"]), round(float(v["person_arrival_t"]), 1)


def compare_studies(
    a: dict[str, Any], b: dict[str, Any], labels: tuple[str, str] = ("a", "b")
) -> dict[str, Any]:
    """How two studies of the same walks (``montecarlo.json`` records) agree: each one's
    summary, and per visit (same episode, cell and entry within 0.1 s; the person's
    walk is the same in both) whether it was guarded in both, in one, or in neither.

    Raises:
        ValueError: the studies did not run the same episodes.
    """
    ea = {e["episode"]: e for e in a["episodes"]}
    eb = {e["episode"]: e for e in b["episodes"]}
    if set(ea) != set(eb) or any(ea[k].get("seed") != eb[k].get("seed") for k in ea):
        raise ValueError("the two studies did not run the same episodes (seed, walks)")
    both = neither = only_a = only_b = unmatched = 0
    differ: list[str] = []
    for name in sorted(ea):
        x, y = ea[name], eb[name]
        if "error" in x or "error" in y:
            continue
        va = {_visit_key(v): v for v in x.get("visits", [])}
        vb = {_visit_key(v): v for v in y.get("visits", [])}
        for key in sorted(set(va) | set(vb)):
            if key not in va or key not in vb:
                unmatched += 1
                continue
            ga, gb = bool(va[key]["guarded"]), bool(vb[key]["guarded"])
            both += ga and gb
            neither += not ga and not gb
            only_a += ga and not gb
            only_b += gb and not ga
            if ga != gb:
                differ.append(f"{name} cell {key[0]} at {key[1]} s")
    matched = both + neither + only_a + only_b
    return {
        "labels": list(labels),
        "summaries": [a["summary"], b["summary"]],
        "visits_matched": matched,
        "visits_unmatched": unmatched,
        "guarded_in_both": both,
        "guarded_in_neither": neither,
        f"guarded_only_{labels[0]}": only_a,
        f"guarded_only_{labels[1]}": only_b,
        "agreement": round((both + neither) / matched, 3) if matched else None,
        "differing_visits": differ,
    }


def comparison_markdown(c: dict[str, Any]) -> str:
    """The comparison as a Markdown table: each study's figures with their intervals."""
    la, lb = c["labels"]
    sa, sb = c["summaries"]

    def rate(s: dict[str, Any], key: str) -> str:
        return f"{_pct(s.get(key))} {_pct_ci(s.get(key + '_ci95'))}"

    def mean(s: dict[str, Any], key: str, ci: str, fmt: str) -> str:
        v = s.get(key)
        return "-" if v is None else f"{fmt.format(v)} {_ci(s.get(ci) or [None], fmt)}"

    rows = [
        ("episodes (failed)", f"{sa['episodes']} ({sa['failed_episodes']})",
         f"{sb['episodes']} ({sb['failed_episodes']})"),
        ("visits", str(sa["visits"]), str(sb["visits"])),
        ("guarded-visit rate", rate(sa, "guarded_rate"), rate(sb, "guarded_rate")),
        ("reachable visits guarded", rate(sa, "guarded_reachable_rate"),
         rate(sb, "guarded_reachable_rate")),
        ("robot in the cell first", rate(sa, "robot_first_rate"), rate(sb, "robot_first_rate")),
        ("mean delay", mean(sa, "mean_delay_s", "mean_delay_ci95_s", "{:.1f} s"),
         mean(sb, "mean_delay_s", "mean_delay_ci95_s", "{:.1f} s")),
        ("false trips per episode",
         mean(sa, "false_trips_per_episode", "false_trips_per_episode_ci95", "{:.2f}"),
         mean(sb, "false_trips_per_episode", "false_trips_per_episode_ci95", "{:.2f}")),
        ("needless trips per episode",
         mean(sa, "needless_trips_per_episode", "needless_trips_per_episode_ci95", "{:.2f}"),
         mean(sb, "needless_trips_per_episode", "needless_trips_per_episode_ci95", "{:.2f}")),
        ("mean warning lead", mean(sa, "mean_warning_lead_s", "mean_warning_lead_ci95_s",
         "{:.1f} s"), mean(sb, "mean_warning_lead_s", "mean_warning_lead_ci95_s", "{:.1f} s")),
        ("warnings timely / late", f"{sa['timely_warnings']} / {sa['late_warnings']}",
         f"{sb['timely_warnings']} / {sb['late_warnings']}"),
        ("wall time per episode", f"{sa.get('wall_s_per_episode')} s",
         f"{sb.get('wall_s_per_episode')} s"),
    ]  # fmt: skip
    lines = [f"| metric (95 % CI) | {la} | {lb} |", "|---|---|---|"]
    lines += [f"| {m} | {x} | {y} |" for m, x, y in rows]
    lines += [
        "",
        f"Per visit: {c['visits_matched']} visits of the same walks, guarded in both "
        f"{c['guarded_in_both']}, in neither {c['guarded_in_neither']}, only {la} "
        f"{c[f'guarded_only_{la}']}, only {lb} {c[f'guarded_only_{lb}']}: the outcome agrees "
        f"on {_pct(c['agreement'])} of visits.",
        "",
    ]
    return "\n".join(lines)
