"""Stage profiles: exclusive seconds per stage and decoder evaluations where they happen."""

import pytest
import torch

from jsrte.model.decoder import Decoder, DecoderConfig
from jsrte.timing import OTHER, count_evaluations, profiling, stage, timed_stage


class FakeClock:
    """Stands in for the ``time`` module: its clocks move only when told to (CPU at twice the wall)."""

    def __init__(self) -> None:
        self.now = 100.0

    def perf_counter(self) -> float:
        return self.now

    def process_time(self) -> float:
        return 2 * self.now


def test_nested_stages_count_exclusive_time(monkeypatch):
    import jsrte.timing

    clock = FakeClock()
    monkeypatch.setattr(jsrte.timing, "time", clock)
    with profiling() as profile:
        clock.now += 1.0  # other
        with stage("outer"):
            clock.now += 2.0
            with stage("inner"):
                clock.now += 5.0
            clock.now += 0.5
        with stage("outer"):  # a stage entered twice adds up
            clock.now += 2.0
    assert profile.seconds == {OTHER: 1.0, "outer": 4.5, "inner": 5.0}
    assert profile.cpu_seconds == {OTHER: 2.0, "outer": 9.0, "inner": 10.0}
    assert profile.total_seconds == 10.5


def test_decoder_evaluations_go_to_the_innermost_stage():
    decoder = Decoder(DecoderConfig(latent_size=4, hidden=16, depth=2, skip_layer=1))
    z = torch.zeros(4)

    @timed_stage("meshing")
    def mesh_like() -> None:
        decoder(torch.zeros(300, 3), z)

    with profiling() as profile:
        decoder(torch.zeros(7, 3), z)
        with stage("solve"):
            decoder(torch.zeros(2, 50, 3), torch.zeros(2, 50, 4))  # batched points count per point
            mesh_like()
    assert profile.evaluations == {OTHER: 7, "solve": 100, "meshing": 300}
    assert profile.total_evaluations == 407
    assert profile.as_dict()["meshing"]["evaluations"] == 300


def test_nothing_is_recorded_without_a_profile():
    with stage("solve"):
        count_evaluations(10)
    with profiling() as profile:
        pass
    assert profile.evaluations == {}
    assert set(profile.seconds) == {OTHER}


def test_an_exception_closes_the_open_stages():
    with pytest.raises(ValueError), profiling() as profile, stage("solve"):
        raise ValueError("boom")
    assert "solve" in profile.seconds
    with stage("after"):  # no profile is left active
        pass
    assert "after" not in profile.seconds
