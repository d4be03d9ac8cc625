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
    first = dec.decode("v1", a)[0]
    again = dec.decode("v1", a)[0]
    assert again is first and seen == [a]
    other = dec.decode("v2", a)[0]  # kept per sender
    assert other == first and len(seen) == 2
    b = b'{"week": 2320, "tow": 11.0}'
    assert dec.decode("v1", b)[0].tow == 11.0 and len(seen) == 3


def test_a_bad_payload_is_rejected_every_time_and_forgets_nothing_valid(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    seen = _counting(monkeypatch)
    dec = RepeatDecoder(EpochTime)
    good = b'{"week": 2320, "tow": 10.0}'
    dec.decode("v1", good)[0]
    bad = b'{"week": -1, "tow": 10.0}'
    for _ in range(2):
        with pytest.raises(BadMessage, match="week"):
            dec.decode("v1", bad)[0]
    assert seen == [good, bad, bad]
    # the last valid payload is still known: a re-send of it costs no validation
    dec.decode("v1", good)[0]
    assert len(seen) == 3


def test_an_oversized_payload_is_rejected_before_it_is_hashed(monkeypatch: pytest.MonkeyPatch) -> None:
    hashed: list[int] = []
    digest = RepeatDecoder.digest

    def counted(payload: bytes) -> bytes:
        hashed.append(len(payload))
        return digest(payload)

    monkeypatch.setattr(RepeatDecoder, "digest", staticmethod(counted))
    dec = RepeatDecoder(EpochTime)
    with pytest.raises(BadMessage, match="too-large"):
        dec.decode("v1", b" " * (codec.MAX_PAYLOAD_BYTES + 1))
    assert hashed == []
    good = b'{"week": 2320, "tow": 10.0}'
    msg, d = dec.decode("v1", good)
    assert msg.tow == 10.0 and d == digest(good) and hashed == [len(good)]
