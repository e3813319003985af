"""Blink-code book: rotation-free binary codes with minimum Hamming distance 3.

Every mote repeats its code word forever (bit ``L-1`` first, one bit per camera
frame period; LED on for a 1 bit). A camera that starts recording at an arbitrary
moment sees some *rotation* of the word, so the book is built such that **every
rotation of every word is at Hamming distance >= 3 from every rotation of every
other word**: no frame or start synchronisation is needed (the scheme of the Oculus
DK2 tracker's rotation-free IDs, with the distance of UVDAR's code book). One or
two wrong bits can never turn one mote's code into a rotation of another's, and a
decoder that accepts only exact matches detects up to two bit errors.

Further rules on each word (so a word looks like an LED and nothing else does):

* *primitive*: its L rotations are all different (a periodic pattern of shorter
  period, which flicker aliasing tends to produce, is never a word);
* weight between ``ceil(L/3)`` and ``L - ceil(L/3)``: enough on bits to be seen and
  enough off bits to measure the background;
* at least two 0->1 transitions per cycle (a lamp switched on once is no word).

The book is built greedily and deterministically: candidate necklaces (the
smallest rotation of each word) in increasing order, accepted when none of their
rotations lies within distance 2 of an already accepted rotation. ``code_book(n)``
returns the shortest length ``L`` whose book holds ``n`` words (lengths 8..24).
Word ``k`` of a book is the code of the ``k``-th mote in the survey's node order.

**Synchronized books** (:func:`sync_code_book`): when every mote starts its word at a
broadcast epoch (and is re-synchronized often enough that its crystal drift stays
below half a bit, see ``docs/blink-codes.md``), the camera knows each sample's bit
position up to one bit: a sample taken near a bit edge may belong to the neighbouring
bit. The book then only needs distance >= 3 between words shifted by at most one
bit against each other (``d(w_i, rot_k(w_j)) >= 3`` for ``i != j``, ``|k| <= 1``),
not between all rotations; the same word rules apply, words need not be the smallest
rotation of their necklace. The decoder tries the expected alignment and the one
neighbouring shift towards the nearer bit edge (:meth:`CodeBook.identify_synchronized`);
a received word within two bit errors of one word at one of those two shifts is never
within two bit errors of another word at either. 100 motes: L = 14 (rotation-free: 16);
1000 motes: L = 18 (rotation-free: 20).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from fgloc.core.errors import FglocError

MIN_DISTANCE = 3
MIN_LENGTH, MAX_LENGTH = 8, 24
#: largest shift (bits) between words that a synchronized book keeps apart (the phase guard)
SYNC_SHIFT = 1


class CodeBookError(FglocError):
    """More motes than any supported code length can label."""


def rotate(word: int, k: int, length: int) -> int:
    """``word`` (``length`` bits) rotated left by ``k`` positions."""
    k %= length
    mask = (1 << length) - 1
    return ((word << k) | (word >> (length - k))) & mask if k else word


def rotations(word: int, length: int) -> list[int]:
    """All ``length`` rotations of ``word`` (rotation k = left by k)."""
    return [rotate(word, k, length) for k in range(length)]


def bits_of(word: int, length: int) -> np.ndarray:
    """Bits of ``word`` in transmission order (most significant of the ``length`` bits first)."""
    return np.array([(word >> (length - 1 - i)) & 1 for i in range(length)], dtype=np.uint8)


def word_of(bits: np.ndarray) -> int:
    """Inverse of :func:`bits_of`."""
    w = 0
    for b in np.asarray(bits, dtype=int):
        w = (w << 1) | int(b)
    return w


def hamming(a: int, b: int) -> int:
    return int(bin(a ^ b).count("1"))


def _ball(length: int, radius: int) -> np.ndarray:
    """XOR masks of weight <= radius (the Hamming ball around 0)."""
    masks = [0]
    for r in range(1, radius + 1):
        for combo in _combinations(length, r):
            masks.append(sum(1 << i for i in combo))
    return np.array(masks, dtype=np.int64)


def _combinations(n: int, r: int) -> list[tuple[int, ...]]:
    from itertools import combinations

    return list(combinations(range(n), r))


def _word_ok(word: int, length: int, canonical: bool = True) -> bool:
    rots = rotations(word, length)
    if (canonical and min(rots) != word) or len(set(rots)) != length:  # not canonical / not primitive
        return False
    w = bin(word).count("1")
    lo = math.ceil(length / 3)
    if not lo <= w <= length - lo:
        return False
    rises = sum(1 for i in range(length) if not (word >> i) & 1 and (word >> ((i + 1) % length)) & 1)
    return rises >= 2


@functools.lru_cache(maxsize=32)
def _greedy_book(length: int, limit: int) -> tuple[int, ...]:
    """Greedy book of ``length``-bit words (at most ``limit`` words), deterministic."""
    forbidden = np.zeros(1 << length, dtype=bool)
    ball = _ball(length, MIN_DISTANCE - 1)
    book: list[int] = []
    for word in range(1, 1 << length):
        if forbidden[word] or not _word_ok(word, length):
            continue
        rots = np.array(rotations(word, length), dtype=np.int64)
        if forbidden[rots].any():
            continue
        book.append(word)
        forbidden[(rots[:, None] ^ ball[None, :]).ravel()] = True
        if len(book) >= limit:
            break
    return tuple(book)


@functools.lru_cache(maxsize=32)
def _greedy_sync_book(length: int, limit: int) -> tuple[int, ...]:
    """Greedy synchronized book: distance >= 3 between distinct words shifted by <= SYNC_SHIFT bits."""
    forbidden = np.zeros(1 << length, dtype=bool)
    ball = _ball(length, MIN_DISTANCE - 1)
    book: list[int] = []
    for word in range(1, 1 << length):
        if forbidden[word] or not _word_ok(word, length, canonical=False):
            continue
        shifted = np.array([rotate(word, k, length) for k in range(-SYNC_SHIFT, SYNC_SHIFT + 1)], dtype=np.int64)
        if forbidden[shifted].any():
            continue
        book.append(word)
        forbidden[(shifted[:, None] ^ ball[None, :]).ravel()] = True
        if len(book) >= limit:
            break
    return tuple(book)


@dataclass(frozen=True)
class CodeBook:
    """``words`` of ``length`` bits. Rotation-free (default): every rotation pair of distinct
    words differs in >= 3 bits. ``synchronized``: distinct words shifted by at most
    :data:`SYNC_SHIFT` bits against each other differ in >= 3 bits (see the module docstring)."""

    length: int
    words: tuple[int, ...]
    synchronized: bool = False

    def __len__(self) -> int:
        return len(self.words)

    def bits(self, index: int) -> np.ndarray:
        """Code of mote ``index`` as 0/1 in transmission order."""
        return bits_of(self.words[index], self.length)

    @functools.cached_property
    def _lookup(self) -> dict[int, tuple[int, int]]:
        return {r: (i, k) for i, w in enumerate(self.words) for k, r in enumerate(rotations(w, self.length))}

    @functools.cached_property
    def _exact(self) -> dict[int, int]:
        return {w: i for i, w in enumerate(self.words)}

    def identify(self, word: int) -> tuple[int, int] | None:
        """(book index, rotation) of an exactly received word, or None (unknown word).
        Rotation-free books only; a synchronized book uses :meth:`identify_synchronized`."""
        if self.synchronized:
            raise ValueError("a synchronized book identifies aligned words: use identify_synchronized")
        return self._lookup.get(word)

    def identify_synchronized(self, word: int, shifts: tuple[int, ...] = (0,)) -> tuple[int, int] | None:
        """(book index, shift) of ``word`` (received in book alignment: bit 0 of the word
        first) when ``rotate(word, -shift)`` is exactly a book word for one of ``shifts``
        (each ``|shift| <= SYNC_SHIFT``, at most two shifts one bit apart); None when none
        or two different words match (never guessed)."""
        if not self.synchronized:
            raise ValueError("identify_synchronized needs a synchronized book")
        if len(shifts) > 2 or any(abs(k) > SYNC_SHIFT for k in shifts) or (
                len(shifts) == 2 and abs(shifts[0] - shifts[1]) > SYNC_SHIFT):
            raise ValueError(f"shifts {shifts}: at most two, {SYNC_SHIFT} bit apart, each within the guard")
        hits = {(self._exact[w], k) for k in shifts if (w := rotate(word, -k, self.length)) in self._exact}
        if len({i for i, _ in hits}) != 1:
            return None
        return min(hits, key=lambda h: abs(h[1]))

    def min_distance(self) -> int:
        """Smallest Hamming distance between two different words under every rotation
        (rotation-free) or every shift of at most :data:`SYNC_SHIFT` bits (synchronized); brute force."""
        if self.synchronized:
            best = self.length
            for i, a in enumerate(self.words):
                for j, b in enumerate(self.words):
                    if i != j:
                        for k in range(-SYNC_SHIFT, SYNC_SHIFT + 1):
                            best = min(best, hamming(a, rotate(b, k, self.length)))
            return best
        rots = [rotations(w, self.length) for w in self.words]
        best = self.length
        for i in range(len(rots)):
            for j in range(i + 1, len(rots)):
                for a in rots[i]:
                    for b in rots[j]:
                        best = min(best, hamming(a, b))
        return best


def _shortest_book(n_motes: int, length: int | None, synchronized: bool) -> CodeBook:
    """The first book of ``length`` bits (or of the lengths MIN_LENGTH..MAX_LENGTH) that holds ``n_motes``."""
    if n_motes < 1:
        raise CodeBookError(f"code book: motes: need at least one ({n_motes})")
    lengths = [length] if length is not None else list(range(MIN_LENGTH, MAX_LENGTH + 1))
    greedy = _greedy_sync_book if synchronized else _greedy_book
    for ln in lengths:
        if not MIN_LENGTH <= ln <= MAX_LENGTH:
            raise CodeBookError(f"code book: length: must be {MIN_LENGTH}..{MAX_LENGTH} bits ({ln})")
        words = greedy(ln, n_motes)
        if len(words) >= n_motes:
            return CodeBook(ln, words[:n_motes], synchronized=synchronized)
    kind = "synchronized book" if synchronized else "book"
    raise CodeBookError(f"code book: motes: more than a {lengths[-1]}-bit {kind} holds ({n_motes})")


def code_book(n_motes: int, length: int | None = None) -> CodeBook:
    """The book for ``n_motes`` motes: at ``length`` bits, or the shortest length that fits."""
    return _shortest_book(n_motes, length, synchronized=False)


def sync_code_book(n_motes: int, length: int | None = None) -> CodeBook:
    """The synchronized book for ``n_motes`` motes (see the module docstring): at ``length``
    bits, or the shortest length that fits. Word ``k`` is the same for every book size."""
    return _shortest_book(n_motes, length, synchronized=True)
