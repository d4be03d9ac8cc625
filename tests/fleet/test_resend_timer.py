"""The lockstep re-send timeout (services/vehicle_agent/resend.py): RFC 6298's estimator over
"epoch sent -> first answer", between `resend_s` and the cap."""

from __future__ import annotations

import pytest

from services.vehicle_agent.resend import MAX_RESEND_S, ResendTimer


def test_before_any_answer_the_timeout_is_the_setting() -> None:
    assert ResendTimer(1.0).timeout_s() == 1.0


def test_quick_answers_keep_the_setting() -> None:
    """A small fleet answered in tens of milliseconds re-sends after `resend_s`, as before."""
    timer = ResendTimer(1.0)
    for _ in range(20):
        timer.answered(0.02)
    assert timer.timeout_s() == 1.0


def test_slow_steady_answers_wait_longer_than_they_take() -> None:
    """Epochs that take 2.4 s to answer (a 1000-vehicle city) are not re-sent after 1 s."""
    timer = ResendTimer(1.0)
    timer.answered(2.4)
    assert timer.timeout_s() == pytest.approx(3 * 2.4)  # first sample: rtt + 4 * rtt / 2
    for _ in range(40):
        timer.answered(2.4)
    assert 2.4 < timer.timeout_s() < 2.6  # the variation decays: rtt + 4 * small


def test_jittery_answers_keep_a_margin() -> None:
    timer = ResendTimer(1.0)
    for i in range(40):
        timer.answered(2.0 if i % 2 else 3.0)
    assert timer.timeout_s() > 3.0


def test_the_timeout_is_capped_so_a_lost_message_is_re_sent() -> None:
    timer = ResendTimer(1.0)
    timer.answered(60.0)
    assert timer.timeout_s() == MAX_RESEND_S
    assert ResendTimer(1.0, max_s=4.0).timeout_s() == 1.0
    capped = ResendTimer(1.0, max_s=4.0)
    capped.answered(60.0)
    assert capped.timeout_s() == 4.0


def test_a_cap_below_the_setting_leaves_the_setting() -> None:
    timer = ResendTimer(5.0, max_s=2.0)
    timer.answered(30.0)
    assert timer.timeout_s() == 5.0
