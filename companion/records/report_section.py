"""A behaviour's figure in a campaign's report (``companion.records.report``), as its registry entry
names it (``companion.procedures.registry``); no plotting library is loaded to name one."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable


@dataclass(frozen=True)
class ReportSection:
    """A behaviour's figure: its title, the PNG's file name and the plot of its stored result (the
    image's file name, or None when there is nothing to draw)."""

    title: str
    file: str
    plot: Callable[[dict, Path], str | None]

    def __post_init__(self) -> None:
        if not self.title or not self.file.endswith(".png"):
            raise ValueError(f"ReportSection needs a title and a .png file name, not {self.title!r}, {self.file!r}")
