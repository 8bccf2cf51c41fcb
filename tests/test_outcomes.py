"""A procedure's outcome is one typed value (``Outcome``), stored and printed as the same words."""
from __future__ import annotations

import json
from dataclasses import dataclass

import pytest

from behaviors.base import Status
from companion.procedures.results import STATUSES, Outcome, ProcedureResult, status_name
from companion.procedures.runner import RunOutcome


@dataclass(frozen=True)
class SpreadFigures:
    """A procedure's figures for these tests: one standard deviation."""

    std_open_deg: float

    def to_dict(self) -> dict:
        return {"std_open_deg": self.std_open_deg}


def test_an_outcome_is_typed_at_construction_and_printed_as_its_word():
    result = ProcedureResult("roll", "completed", None, SpreadFigures(1.5))
    assert result.status is Outcome.COMPLETED and result.completed
    assert json.dumps(result.to_json()) == '{"std_open_deg": 1.5, "status": "completed", "pilot_has_it": false, ' \
                                           '"restore_problems": []}'
    assert f"{Outcome.NOT_STARTED}" == "not started" and STATUSES[-1] == "running"
    assert RunOutcome("aborted", "link lost", {}).status is Outcome.ABORTED
    assert status_name(Status.FAILURE) is Outcome.FAILED


@pytest.mark.parametrize("word", ["done", "Completed", ""])
def test_a_word_that_is_no_outcome_is_refused_with_the_words_there_are(word):
    with pytest.raises(ValueError, match="completed, failed, aborted, refused, not started, running"):
        ProcedureResult("roll", word)
    with pytest.raises(ValueError, match="an outcome is one of"):
        RunOutcome(word, None, {})
