"""Blink code book: distance over all rotations, rotation-free identification, word rules."""

from __future__ import annotations

import numpy as np
import pytest

from fgloc.camera.blink_codes import CodeBook, CodeBookError, bits_of, code_book, hamming, rotate, rotations, word_of


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
