"""What the two SITL log recorders share: stopping the simulator child they started, and keeping
the largest log it wrote (the flown mission's; a boot may leave an empty one beside it)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path


def stop_child(child: subprocess.Popen, timeout_s: float) -> None:
    """SIGTERM, then SIGKILL if the child has not exited within ``timeout_s``."""
    child.terminate()
    try:
        child.wait(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        child.kill()


def keep_largest_log(folder: Path, pattern: str, out: Path, what: str) -> None:
    """Copy the largest file matching ``pattern`` under ``folder`` to ``out``; RuntimeError naming
    ``what`` when there is none."""
    logs = sorted(Path(folder).glob(pattern), key=lambda p: p.stat().st_size)
    if not logs:
        raise RuntimeError(f"{what} in {folder}")
    out.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(logs[-1], out)
