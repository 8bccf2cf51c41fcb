"""A computation run beside the control loop: the loop keeps ticking (nothing commanded) until the
result is there, then its commands; a failure in the computation is the step's, with its message."""
from __future__ import annotations

import threading

from behaviors.background import BackgroundStep
from behaviors.base import Status
from companion.interface import StatusText, Telemetry


def test_the_loop_keeps_ticking_until_the_result_is_there():
    release = threading.Event()
    step = BackgroundStep(lambda: (release.wait(10.0), 42)[1], lambda result: [StatusText(f"got {result}")],
                          name="design")
    ticks = [step.tick(Telemetry(time_s=0.1 * k)) for k in range(5)]  # the work is still waiting
    assert all(commands == [] for commands in ticks) and not step.done
    release.set()
    step._done.wait(10.0)
    commands = step.tick(Telemetry(time_s=0.6))
    assert step.status is Status.SUCCESS and [c.text for c in commands] == ["got 42"]


def test_a_failing_computation_fails_the_step_with_its_reason():
    def work():
        raise ValueError("no accepted model")

    step = BackgroundStep(work, lambda result: [], name="design")
    step.tick(Telemetry(time_s=0.0))
    step._done.wait(10.0)
    step.tick(Telemetry(time_s=0.1))
    assert step.status is Status.FAILURE and "no accepted model" in step.reason
