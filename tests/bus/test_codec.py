"""`RepeatDecoder`: a byte-identical re-send is not validated again, and nothing else changes."""

from __future__ import annotations

import pytest

from coplane.bus import BadMessage, RepeatDecoder, codec
from coplane.messages import EpochTime


def _counting(monkeypatch: pytest.MonkeyPatch) -> list[bytes]:
    seen: list[bytes] = []
    decode = codec.decode

    def counted(model: type[EpochTime], payload: bytes) -> EpochTime:
        seen.append(payload)
        return decode(model, payload)

    monkeypatch.setattr(codec, "decode", counted)
    return seen


def test_a_resend_is_the_same_message_without_a_second_validation(monkeypatch: pytest.MonkeyPatch) -> None:
    seen = _counting(monkeypatch)
    dec = RepeatDecoder(EpochTime)
    a = b'{"week": 2320, "tow": 10.0}'
    first = dec.decode("v1", a, RepeatDecoder.digest(a))
    again = dec.decode("v1", a, RepeatDecoder.digest(a))
    assert again is first and seen == [a]
    other = dec.decode("v2", a, RepeatDecoder.digest(a))  # kept per sender
    assert other == first and len(seen) == 2
    b = b'{"week": 2320, "tow": 11.0}'
    assert dec.decode("v1", b, RepeatDecoder.digest(b)).tow == 11.0 and len(seen) == 3


def test_a_bad_payload_is_rejected_every_time_and_forgets_nothing_valid(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen = _counting(monkeypatch)
    dec = RepeatDecoder(EpochTime)
    good = b'{"week": 2320, "tow": 10.0}'
    dec.decode("v1", good, RepeatDecoder.digest(good))
    bad = b'{"week": -1, "tow": 10.0}'
    for _ in range(2):
        with pytest.raises(BadMessage, match="week"):
            dec.decode("v1", bad, RepeatDecoder.digest(bad))
    assert seen == [good, bad, bad]
    # the last valid payload is still known: a re-send of it costs no validation
    dec.decode("v1", good, RepeatDecoder.digest(good))
    assert len(seen) == 3
