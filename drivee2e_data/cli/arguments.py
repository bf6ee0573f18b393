"""Argument types and helpers shared by the command groups."""

from __future__ import annotations

import argparse

from drivee2e_data import splits
from drivee2e_data.sensors.camera_labels import LABEL_KINDS
from drivee2e_data.sources.cutting import CUT_MODES


def _positive(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _workers(text: str) -> int | str:
    return "auto" if text == "auto" else _positive(text)


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text}")
    return value


def _label_kinds(text: str) -> tuple[str, ...]:
    kinds = tuple(k.strip() for k in text.split(",") if k.strip())
    unknown = [k for k in kinds if k not in LABEL_KINDS]
    if unknown or not kinds:
        raise argparse.ArgumentTypeError(
            f"{text!r}: expected some of {','.join(LABEL_KINDS)}, comma-separated"
        )
    return kinds


def _add_cut_arguments(command: argparse.ArgumentParser) -> None:
    command.add_argument(
        "--cut",
        choices=CUT_MODES,
        default="ego",
        help="how recordings longer than 1.5 clips are cut: a clip per vehicle passing through "
        "the junction (ego, default) or fixed windows",
    )
    command.add_argument(
        "--clip-seconds",
        type=_positive_float,
        default=20.0,
        help="window length for --cut windows (default 20)",
    )


def _split_options(parser: argparse.ArgumentParser, default: str) -> None:
    parser.add_argument("--split", choices=(*splits.SPLITS, "all"), default=default)
    parser.add_argument(
        "--split-name", default="default", help="DATA/splits/NAME.csv, or a .csv path"
    )


def _cell(value: float | None, key: str) -> str:
    if value is None or value != value:
        return "-"
    return f"{100 * value:.2f}%" if key.startswith("collision") else f"{value:.2f}"


def _size(text: str) -> tuple[int, int]:
    try:
        width, height = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WxH such as 1600x900, got {text!r}") from None
    if width < 16 or height < 16:
        raise argparse.ArgumentTypeError(f"image size {text}: expected at least 16x16")
    return width, height


def _print_table(header: tuple[str, ...], rows: list[tuple[str, ...]]) -> None:
    widths = [max(len(str(r[k])) for r in [header, *rows]) for k in range(len(header))]
    for row in [header, *rows]:
        cells = (str(cell).ljust(width) for cell, width in zip(row, widths, strict=True))
        print("  ".join(cells).rstrip())
