"""Blink code book: distance over all rotations, rotation-free identification, word rules."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.camera.blink_codes import (
    SYNC_SHIFT,
    CodeBook,
    CodeBookError,
    bits_of,
    code_book,
    hamming,
    rotate,
    rotations,
    sync_code_book,
    word_of,
)


@pytest.mark.parametrize("n", [10, 100])
def test_min_distance_over_rotations(n: int) -> None:
    book = code_book(n)
    assert len(book) == n
    assert book.min_distance() >= 3  # brute force over every rotation pair


def test_book_for_1000_motes_sampled_distance() -> None:
    book = code_book(1000)
    assert book.length == 20
    rng = np.random.default_rng(0)
    for i, j in rng.choice(1000, size=(300, 2)):
        if i == j:
            continue
        d = min(hamming(a, b) for a in rotations(book.words[i], 20) for b in rotations(book.words[j], 20))
        assert d >= 3


def test_every_rotation_identifies_its_word_and_one_bit_error_never_does() -> None:
    book = code_book(50)
    for i, w in enumerate(book.words):
        for k in range(book.length):
            r = rotate(w, k, book.length)
            assert book.identify(r) == (i, k)
            for b in range(book.length):  # one wrong bit: detected (no exact match at all)
                assert book.identify(r ^ (1 << b)) is None


def test_word_rules() -> None:
    book = code_book(100)
    L = book.length
    for w in book.words:
        rots = rotations(w, L)
        assert len(set(rots)) == L  # primitive
        weight = bin(w).count("1")
        assert L // 3 <= weight <= L - L // 3


def test_bits_round_trip_and_order() -> None:
    assert list(bits_of(0b1011, 4)) == [1, 0, 1, 1]
    assert word_of(np.array([1, 0, 1, 1])) == 0b1011
    assert rotate(0b1000, 1, 4) == 0b0001


def test_errors() -> None:
    with pytest.raises(CodeBookError):
        code_book(0)
    with pytest.raises(CodeBookError):
        code_book(10, length=40)
    assert isinstance(code_book(5, length=12), CodeBook)


# ----- synchronized books -------------------------------------------------------------------
def _popcount(x: np.ndarray) -> np.ndarray:
    return np.unpackbits(x.astype(">u4").view(np.uint8).reshape(*x.shape, 4), axis=-1).sum(axis=-1)


@pytest.mark.parametrize(("n", "length"), [(100, 14), (1000, 18)])
def test_synchronized_book_distance_by_brute_force(n: int, length: int) -> None:
    book = sync_code_book(n)
    assert book.synchronized and len(book) == n and book.length == length
    w = np.array(book.words, dtype=np.int64)
    for k in range(-SYNC_SHIFT, SYNC_SHIFT + 1):  # every pair of different words, every shift within the guard
        shifted = np.array([rotate(int(x), k, length) for x in w], dtype=np.int64)
        d = _popcount(w[:, None] ^ shifted[None, :])
        np.fill_diagonal(d, length)
        assert d.min() >= 3, (k, d.min())
    if n == 100:
        assert book.min_distance() >= 3
    assert sync_code_book(37, length).words == book.words[:37]  # prefix: the firmware's one table per length
    for x in book.words:  # the same word rules as the rotation-free book
        assert len(set(rotations(x, length))) == length
        assert -(-length // 3) <= bin(x).count("1") <= length - -(-length // 3)


def test_synchronized_identification_tolerates_one_shift_never_two_errors() -> None:
    book = sync_code_book(100)
    L = book.length
    for i, w in enumerate(book.words):
        assert book.identify_synchronized(w) == (i, 0)
        assert book.identify_synchronized(rotate(w, -1, L), (0, -1)) == (i, -1)
        assert book.identify_synchronized(rotate(w, 1, L), (0, 1)) == (i, 1)
    rng = np.random.default_rng(1)
    for i in rng.choice(100, 25, replace=False).tolist():
        for s in (-1, 0, 1):
            shifts = (0, s) if s else (0, -1)
            r = rotate(book.words[i], s, L)
            for a in range(L):  # every one- and two-bit error: identified as the right word or not at all
                for b in range(a, L):
                    hit = book.identify_synchronized(r ^ (1 << a) ^ (1 << b), shifts)
                    assert hit is None or hit[0] == i
    with pytest.raises(ValueError):
        book.identify(book.words[0])
    with pytest.raises(ValueError):
        book.identify_synchronized(book.words[0], (-1, 1))  # two bits apart: outside the guarantee
    with pytest.raises(ValueError):
        code_book(10).identify_synchronized(0)


def test_synchronized_broadcast_message_round_trip() -> None:
    from fgloc.drivers.tinyos.blink import BlinkBroadcast, BlinkField, blink_broadcast, parse_blink_command

    cmd = BlinkBroadcast(14, 1, 100, 0.01668, synchronized=True)
    payload = cmd.payload()
    assert payload.hex() == "030e000100640684" + "0000"
    assert BlinkBroadcast.from_payload(payload) == cmd
    assert BlinkBroadcast.from_payload(BlinkBroadcast(16, 1, 100, 0.01668).payload()).synchronized is False
    packet = blink_broadcast(cmd)
    assert parse_blink_command(packet) == cmd
    field = BlinkField()
    reports = field.handle(packet)
    assert len(reports) == 100
    assert field.running[5] == (14, sync_code_book(100).words[4])
