"""Signals against the restore: two Ctrl-C 0.01 s apart used to cut a parameter write
of the restore (HDG_I left at 0.00584). Now a restore is never interrupted, each item is retried, and
only a third signal exits — after printing what is still unrestored."""
from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from behaviors.base import Footprint
from companion.procedures.app import AbortFlag, install_signal_handlers
from companion.procedures.restore import RestorePoint
from companion.procedures.restore_items import RESTORE_TRIES

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")

FAKE = textwrap.dedent('''
    import os, signal

    from companion.link.profiles import ARDUROVER
    from harness.port_stub import PortStub


    class SignallingFake(PortStub):
        """An ArduRover-like parameter store whose restore writes are each hit by signals."""

        def __init__(self, signals=0, flaky=()):
            super().__init__(ARDUROVER)
            self.params = {"ATC_STR_ANG_P": 2.0, "ATC_STR_RAT_P": 0.2, "ATC_STR_RAT_I": 0.2,
                           "ATC_STR_RAT_D": 0.01, "ATC_STR_RAT_FF": 0.2, "ATC_STR_RAT_IMAX": 1.0}
            self.signals = signals  # sent all at once, at the first restore write
            self.flaky = dict.fromkeys(flaky, 1)  # name -> failures left
            self.restoring = False

        def get_param(self, name):
            return self.params[name]

        def set_param(self, name, value):
            if self.restoring:
                for _ in range(self.signals):
                    os.kill(os.getpid(), signal.SIGINT)  # delivered between these bytecodes
                self.signals = 0
                if self.flaky.get(name):
                    self.flaky[name] -= 1
                    raise TimeoutError(f"{name}: no PARAM_VALUE")
            self.params[name] = value
            return value

        def get_params(self, names):
            return {n: 0.0 for n in names}

        def release(self, actuator=None):
            pass

        def set_mode(self, mode):
            self.mode = mode
''')

GAINS = Footprint.of(parameters=("heading_angle_p", "heading_rate_p", "heading_rate_i", "heading_rate_d",
                                 "heading_rate_ff", "heading_rate_imax"))


@pytest.fixture
def fake_module(tmp_path, monkeypatch):
    (tmp_path / "signalling_fake.py").write_text(FAKE)
    monkeypatch.syspath_prepend(str(tmp_path))
    import signalling_fake

    return signalling_fake


def _changed(link) -> dict[str, float]:
    found = dict(link.params)
    for name in link.params:
        link.params[name] *= 3.0  # what a procedure wrote
    return found


def test_two_signals_during_the_restore_neither_cut_it_nor_leave_a_gain(fake_module):
    link = fake_module.SignallingFake(signals=2)  # the abort request and a second, 0 s apart
    flag, messages = AbortFlag(), io.StringIO()
    undo = install_signal_handlers(flag, stream=messages)
    try:
        point = RestorePoint.capture(link, GAINS)
        found = _changed(link)
        flag.guard.active = 1  # a procedure is ending (as run_procedure marks it)
        link.restoring = True
        problems = point.restore(link, guard=flag.guard)
    finally:
        undo()
    assert problems == []
    assert link.params == found  # every gain back, although the first write drew two signals
    assert "restoring the vehicle" in messages.getvalue()
    assert flag.reason == "signal SIGINT"


def test_each_item_is_retried(fake_module):
    link = fake_module.SignallingFake(flaky=("ATC_STR_RAT_I",))
    point = RestorePoint.capture(link, GAINS)
    found = _changed(link)
    link.restoring = True
    assert RESTORE_TRIES >= 2
    assert point.restore(link) == []
    assert link.params == found


def test_a_third_signal_exits_at_once_and_says_what_is_not_restored(fake_module, tmp_path):
    script = tmp_path / "third.py"
    script.write_text(textwrap.dedent('''
        import sys
        from behaviors.base import Footprint
        from companion.procedures.app import AbortFlag, install_signal_handlers
        from companion.procedures.runner import RestorePoint
        from signalling_fake import SignallingFake

        GAINS = Footprint.of(parameters=("heading_angle_p", "heading_rate_p", "heading_rate_i"))
        link = SignallingFake(signals=3)
        flag = AbortFlag()
        install_signal_handlers(flag)
        point = RestorePoint.capture(link, GAINS)
        for name in link.params:
            link.params[name] *= 3.0  # what the procedure wrote
        flag.guard.active = 1
        link.restoring = True
        point.restore(link, guard=flag.guard)
        print("restore finished")  # never reached: the third signal exits during the first write
    '''))
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), *sys.path]))
    done = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=60, env=env)
    assert done.returncode == 130, done.stderr[-2000:]
    assert "restore finished" not in done.stdout
    forced = [line for line in done.stderr.splitlines() if line.startswith("forced exit: NOT restored:")]
    assert len(forced) == 1
    # the first parameter write was under way: it and everything after it are named
    assert "release overrides" not in forced[0] and "restore ATC_STR_ANG_P" in forced[0]
    assert "restore mode" in forced[0]


def test_a_second_ctrl_c_still_breaks_a_blocking_call_inside_the_step_loop():
    flag = AbortFlag()
    undo = install_signal_handlers(flag, stream=io.StringIO())
    try:
        flag.guard.active, flag.guard.interruptible = 1, True
        os.kill(os.getpid(), signal.SIGINT)  # the abort request
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            signal.sigtimedwait([], 0.1) if hasattr(signal, "sigtimedwait") else None
    finally:
        undo()


@pytest.mark.parametrize("protecting", [True, False])
def test_the_countdown_to_a_forced_exit_is_said_only_where_one_happens(protecting):
    """During a restore the second SIGTERM says one more forces the exit (the third does); with
    nothing to protect the signals end the loop and no countdown is promised that never comes."""
    import os
    import signal as signals

    flag, messages = AbortFlag(), io.StringIO()
    flag.guard.active, flag.guard.restoring = (1, True) if protecting else (0, False)
    exits = []
    undo = install_signal_handlers(flag, stream=messages)
    real_exit = os._exit
    os._exit = exits.append  # the third signal during a restore exits: observed, not taken
    try:
        for _ in range(3):
            os.kill(os.getpid(), signals.SIGTERM)
    finally:
        os._exit = real_exit
        undo()
    said = messages.getvalue()
    if protecting:
        assert "signal 1 more time(s) to exit without restoring" in said and exits == [130]
    else:
        assert "more time" not in said and said.count("stopping: nothing to restore") == 2 and exits == []
