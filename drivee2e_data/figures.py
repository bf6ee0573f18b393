"""Figures a person would rather look at than read (needs the `viz` extra: matplotlib)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from drivee2e_data.errors import DriveE2EError


def plot_statistics(stats: dict[str, Counter[str]], path: Path, title: str = "") -> None:
    """The four-panel dataset figure (behaviour, agent class, weather, time of day) as a PNG."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError as error:
        raise DriveE2EError("plots need matplotlib: pip install 'drivee2e-data[viz]'") from error
    figure, axes = plt.subplots(1, 4, figsize=(16, 3.6), dpi=100)
    colours = ("#d62728", "#1f77b4", "#2ca02c", "#ff7f0e")
    for ax, (name, counts), colour in zip(axes, stats.items(), colours, strict=True):
        labels, values = list(counts), list(counts.values())
        bars = ax.bar(range(len(labels)), values, color=colour)
        ax.set_xticks(range(len(labels)), labels, rotation=40, ha="right", fontsize=8)
        ax.set_title(name)
        ax.bar_label(bars, fontsize=7)
        ax.set_ylabel("tracks" if name == "agent class" else "clips")
    if title:
        figure.suptitle(title)
    figure.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)
    plt.close(figure)
