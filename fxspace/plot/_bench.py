"""The benchmark page's figure: our time and each peer's, and the speed-up per case."""

from __future__ import annotations

from typing import Any

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

__all__ = ["plot_bench_record"]


def plot_bench_record(rec: dict[str, Any]) -> Figure:
    """Time of ours and of each peer (log scale) against size — or per case when the rows
    have no sizes — and the ratio peer / ours per case, labelled.

    **Arguments:** ``rec`` a benchmark record (`fxspace.runs.write_bench`: ``title`` and
    ``rows`` with ``case``, ``size``, ``ours``, ``peer``, ``ours_s``, ``peer_s``,
    ``ratio``).

    **Returns:** the `Figure` (two panels).
    """
    rows = rec["rows"]
    sized = len({r["size"] for r in rows if r["size"] is not None}) >= 2
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 3.8))
    pairs = list(dict.fromkeys((r["ours"], r["peer"]) for r in rows))
    if sized:
        for ours, peer in pairs:
            rr = sorted((r for r in rows if (r["ours"], r["peer"]) == (ours, peer)
                         and r["size"] is not None), key=lambda r: r["size"])  # fmt: skip
            x = [r["size"] for r in rr]
            ax.plot(x, [r["ours_s"] for r in rr], "o-", label=f"ours: {ours}")
            ax.plot(x, [r["peer_s"] for r in rr], "s--", label=f"{peer}")
        ax.set_xlabel("size")
    else:
        x = range(len(rows))
        ax.bar([i - 0.2 for i in x], [r["ours_s"] for r in rows], 0.4, label="ours")
        ax.bar([i + 0.2 for i in x], [r["peer_s"] for r in rows], 0.4, label="peer")
        ax.set_xticks(list(x), [r["case"] for r in rows], rotation=20, ha="right", fontsize=7)
    ax.set_yscale("log")
    ax.set_ylabel("median time (s)")
    ax.set_title("time: ours and the peers")
    ax.legend(fontsize=7)
    labels = [r["case"] for r in rows]
    ratios = [r["ratio"] or 0.0 for r in rows]
    bx.barh(range(len(rows)), ratios, color=["tab:green" if v >= 1 else "tab:red" for v in ratios])
    bx.axvline(1.0, color="k", lw=0.8)
    bx.set_yticks(range(len(rows)), labels, fontsize=7)
    bx.set_xlabel("peer time / our time (> 1: ours faster)")
    bx.set_title("speed-up")
    fig.suptitle(rec["title"], fontsize=10)
    fig.tight_layout()
    return fig


