"""The trial runner's frame -> estimate lockstep: a slow frame is waited for, a lost one sent again."""

import time
from types import SimpleNamespace

import pytest

from ipc.messages import StatusReply
from launch_scripts.trial_runner.trial import _Link


class _Service:
    """Stands in for the perception service's sockets: the estimate of a frame comes
    ``tracking_s`` after the first copy of it that was not lost (the first ``lose`` copies are)."""

    def __init__(self, tracking_s: float, lose: int = 0, state: str = "tracking"):
        self.tracking_s, self.lose, self.state = tracking_s, lose, state
        self.published, self.tracked_at = [], None

    def publish(self, frame):
        self.published.append(frame.seq)
        if len(self.published) > self.lose and self.tracked_at is None:
            self.tracked_at = time.monotonic() + self.tracking_s

    def recv_latest(self, timeout_s):
        time.sleep(timeout_s)
        if self.tracked_at is not None and time.monotonic() >= self.tracked_at:
            return SimpleNamespace(seq=self.published[-1])
        return None

    def request(self, request):
        # the service answers between frames: after the frame it is tracking
        if self.tracked_at is not None:
            time.sleep(max(0.0, self.tracked_at - time.monotonic()))
            return StatusReply(request_id=request.request_id, state=self.state, last_seq=self.published[-1])
        return StatusReply(request_id=request.request_id, state=self.state, last_seq=-1,
                           message="frame 0: initialisation failed: the object is too large")


def _link(service, timeout_s=10.0):
    return SimpleNamespace(frames_pub=service, estimates=service, control=service,
                           children=SimpleNamespace(check=lambda: None),
                           config=SimpleNamespace(frame_timeout_s=timeout_s))


def test_a_slow_frame_is_waited_for_not_tracked_twice():
    service = _Service(tracking_s=1.3)
    estimate = _Link.estimate_of(_link(service), SimpleNamespace(seq=7))
    assert estimate.seq == 7
    assert service.published == [7]


def test_a_lost_frame_is_sent_again():
    service = _Service(tracking_s=0.1, lose=1)
    assert _Link.estimate_of(_link(service), SimpleNamespace(seq=3)).seq == 3
    assert service.published == [3, 3]


def test_no_estimate_times_out():
    service = _Service(tracking_s=0.1, lose=100)
    with pytest.raises(TimeoutError, match="no estimate of frame 5 within 1 s"):
        _Link.estimate_of(_link(service, timeout_s=1.0), SimpleNamespace(seq=5))
    assert len(service.published) >= 2


def test_a_service_that_went_idle_is_not_waited_for():
    service = _Service(tracking_s=0.1, lose=100, state="idle")
    started = time.monotonic()
    with pytest.raises(TimeoutError, match=r"no estimate of frame 0: the perception service is idle \(frame 0: "
                                           r"initialisation failed: the object is too large\)"):
        _Link.estimate_of(_link(service, timeout_s=30.0), SimpleNamespace(seq=0))
    assert time.monotonic() - started < 5.0
