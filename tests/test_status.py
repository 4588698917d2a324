"""Statuses and severities are declared once (:mod:`hdrcore.status`, issue 17): the result
types are annotated with those aliases, and every word real runs write is a declared one."""

from __future__ import annotations

import json
import typing
from pathlib import Path

import pytest

from hdrcore import status
from hdrcore.batch.index import read_index
from hdrcore.batch.task import BracketRecord
from hdrcore.diagnose import Verdict
from hdrcore.errors import InputError
from hdrcore.exposure import BracketExposureResult, ExposureRatioResult
from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.registration import FAILED_STATUSES, PairRegistration
from hdrcore.registration.local import LocalFrame
from hdrcore.registration.residual import RESIDUAL_STATUSES, ResidualMotion
from hdrcore.response import ResponseCurve, srgb_response
from hdrcore.signal import FrameSignal
from hdrcore.synthetic.faults import (
    SEED_PROTOCOL,
    write_black_frames,
    write_swapped_times,
)

SMALL = SEED_PROTOCOL.replace(shape=(48, 64), exposure_times=(1.0, 4.0, 16.0, 64.0))


@pytest.mark.parametrize(
    "cls,field,alias",
    [
        (Verdict, "severity", status.Severity),
        (ExposureRatioResult, "status", status.RatioStatus),
        (BracketExposureResult, "status", status.ChainStatus),
        (FrameSignal, "status", status.SignalStatus),
        (BracketRecord, "status", status.BatchStatus),
        (ResponseCurve, "status", status.ResponseStatus),
        (PairRegistration, "status", status.RegistrationStatus),
        (ResidualMotion, "status", status.ResidualStatus),
        (LocalFrame, "before_status", status.ResidualStatus),
        (LocalFrame, "after_status", status.ResidualStatus),
    ],
)
def test_result_fields_use_the_declared_aliases(cls, field, alias) -> None:
    assert typing.get_type_hints(cls)[field] == alias


def test_the_tuples_list_the_aliases_words() -> None:
    assert status.SEVERITIES == ("error", "warning", "info")
    assert set(status.RATIO_STATUSES) >= {"ok", "uncertain", "no-overlap", "no-signal"}
    for words in (
        status.SEVERITIES,
        status.RATIO_STATUSES,
        status.CHAIN_STATUSES,
        status.SIGNAL_STATUSES,
    ):
        assert len(set(words)) == len(words) and all(isinstance(w, str) for w in words)


@pytest.mark.parametrize("case", ["black", "swapped"])
def test_every_word_a_run_writes_is_declared(tmp_path: Path, case: str) -> None:
    if case == "black":
        c = write_black_frames(tmp_path, (0,), SMALL)
        bracket = load_bracket(c.frames)
    else:
        c = write_swapped_times(tmp_path, spec=SMALL)
        bracket = load_bracket(c.frames, exposure_times=c.times_file)
    result = Pipeline(bracket, PipelineParams()).run(until="merge")
    doc = json.loads(json.dumps(result.to_report(), default=str))
    severities = {v["severity"] for v in doc["verdicts"]}
    pair_statuses = {p["status"] for p in doc["ratios"]["pairs"]}
    signal_statuses = {s["status"] for s in doc["frame_signal"]}
    assert severities == {v.severity for v in result.verdicts}
    assert severities <= set(status.SEVERITIES)
    assert pair_statuses <= set(status.RATIO_STATUSES)
    assert {p.status for p in result.exposures_histogram.pairs} <= set(status.RATIO_STATUSES)
    assert result.exposures.status in status.CHAIN_STATUSES
    assert result.exposures_histogram.status in status.CHAIN_STATUSES
    assert signal_statuses <= set(status.SIGNAL_STATUSES)
    assert result.response is None or result.response.status in status.RESPONSE_STATUSES
    for q in result.registration.pairs:
        assert q.status in status.REGISTRATION_STATUSES
        assert q.residual is None or q.residual.status in status.RESIDUAL_STATUSES
    if case == "black":  # runs that report something other than "ok"
        assert "black" in signal_statuses
    else:
        assert severities & {"warning", "error"}


def test_the_registration_words_are_the_modules_own() -> None:
    assert FAILED_STATUSES == status.FAILED_REGISTRATION_STATUSES
    assert set(status.REGISTRATION_STATUSES) == {"ok", "weak", *FAILED_STATUSES}
    assert RESIDUAL_STATUSES == status.RESIDUAL_STATUSES


def test_a_record_read_back_with_an_unknown_status_is_refused(tmp_path: Path) -> None:
    """A batch record read back names its status; an unknown word (a damaged or foreign index)
    is a clear error naming the file, not a bracket taken as done."""
    rec = BracketRecord(name="b", files=("a.jpg",), status="warning")
    assert BracketRecord.from_json(rec.to_json()) == rec
    bad = {**rec.to_json(), "status": "success"}
    with pytest.raises(ValueError, match="unknown bracket status 'success'"):
        BracketRecord.from_json(bad)
    (tmp_path / "index.json").write_text(json.dumps({"brackets": [bad]}))
    with pytest.raises(InputError, match="not a batch index.*success") as info:
        read_index(tmp_path)
    assert info.value.path is not None and info.value.path.endswith("index.json")


def test_a_saved_curve_with_an_unknown_status_is_refused(tmp_path: Path) -> None:
    curve = srgb_response(255, 3)
    assert curve.status in status.RESPONSE_STATUSES
    path = curve.save(tmp_path / "curve.json")
    assert ResponseCurve.load(path).status == curve.status
    doc = json.loads(path.read_text())
    doc["status"] = "success"
    path.write_text(json.dumps(doc))
    with pytest.raises(InputError, match="unknown status 'success'") as info:
        ResponseCurve.load(path)
    assert info.value.path == str(path)
