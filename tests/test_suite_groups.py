"""The suite's own scheduling: tests marked ``xdist_group`` run on one worker (``--dist loadgroup``,
pyproject.toml). The SITL tests rely on it (one firmware at a time), and so do the module fixtures
that make a rehearsal or a sweep once. pytest-xdist does it by suffixing each such test's id with its
group; where a pytest release keeps ids where xdist cannot reach them, every group is silently
ignored, which this test tells."""
from __future__ import annotations

import os

import pytest


@pytest.mark.xdist_group("suite-groups")
def test_a_grouped_test_carries_its_group_when_the_suite_runs_on_workers(request):
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        pytest.skip("not on an xdist worker: nothing is scheduled by group")
    if request.config.getvalue("dist") != "loadgroup" and not request.config.getvalue("loadgroup"):
        pytest.skip("the suite was not started with --dist loadgroup")
    assert request.node.nodeid.endswith("@suite-groups"), (
        f"{request.node.nodeid}: pytest-xdist could not mark this test's group, so xdist_group is ignored "
        "(pytest 9 with pytest-xdist 3.8: keep pytest below 9, pyproject.toml)")
