"""SITL's own vehicles as the rig starts them (harness.own_sitl): what it refuses before any process."""
from __future__ import annotations

import pytest

from harness.own_sitl import MOTORBOAT, OWN_VEHICLES, VECTORED_ROV, OwnSitl, OwnVehicle


def test_a_missing_build_is_named_before_any_process_starts(tmp_path):
    sitl = OwnSitl(str(tmp_path / "build" / "sitl" / "bin"), MOTORBOAT, workdir=tmp_path / "work")
    with pytest.raises(FileNotFoundError, match="ardurover"):
        sitl.start()
    assert sitl.process is None and sitl.stop() is None


def test_the_rig_refuses_a_speed_up_of_zero_and_a_vehicle_without_files():
    with pytest.raises(ValueError, match="speedup"):
        OwnSitl("/nowhere", VECTORED_ROV, speedup=0.0)
    with pytest.raises(ValueError):
        OwnVehicle("ardurover", "motorboat", ())


def test_the_boats_ship_calm_and_the_rov_armable_from_one_client():
    assert dict(OWN_VEHICLES["motorboat"].rig) == {"SIM_WAVE_ENABLE": 0.0, "SIM_WIND_SPD": 0.0}
    assert OWN_VEHICLES["motorboat-skid"].defaults[-1] == "rover-skid.parm"
    assert dict(OWN_VEHICLES["sitl-rov"].rig) == {"FS_PILOT_INPUT": 0.0, "FS_GCS_ENABLE": 0.0}
