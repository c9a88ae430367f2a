"""A brute-force broadphase in numpy: the oracle the package's engines are checked against."""

import numpy as np


class Oracle:
    """Every pair of live boxes tested, with the engines' filter rule: a pair is tracked iff
    (a.category & b.mask) and (b.category & a.mask) are non-zero and not both are static."""

    def __init__(self, dims):
        self.dims = dims
        self.boxes = {}  # key -> (lo, hi, category, mask, static)

    def insert(self, keys, lo, hi, category=None, mask=None, static=None):
        n = len(keys)
        category = np.broadcast_to(np.uint64(1) if category is None else category, (n,))
        mask = np.broadcast_to(np.uint64(2**64 - 1) if mask is None else mask, (n,))
        static = np.broadcast_to(False if static is None else static, (n,))
        for i, k in enumerate(keys):
            self.boxes[int(k)] = (np.array(lo[i]), np.array(hi[i]), int(category[i]),
                                  int(mask[i]), bool(static[i]))

    def update(self, keys, lo, hi):
        for i, k in enumerate(keys):
            _, _, c, m, s = self.boxes[int(k)]
            self.boxes[int(k)] = (np.array(lo[i]), np.array(hi[i]), c, m, s)

    def erase(self, keys):
        for k in keys:
            del self.boxes[int(k)]

    def pairs(self):
        """The tracked overlapping pairs, uint64[p, 2] sorted, (smaller key, larger key)."""
        if len(self.boxes) < 2:
            return np.zeros((0, 2), np.uint64)
        keys = np.array(sorted(self.boxes), np.uint64)
        lo = np.array([self.boxes[int(k)][0] for k in keys], np.float64)
        hi = np.array([self.boxes[int(k)][1] for k in keys], np.float64)
        cat = np.array([self.boxes[int(k)][2] for k in keys], np.uint64)
        msk = np.array([self.boxes[int(k)][3] for k in keys], np.uint64)
        st = np.array([self.boxes[int(k)][4] for k in keys], bool)
        overlap = np.all((lo[:, None, :] <= hi[None, :, :]) & (lo[None, :, :] <= hi[:, None, :]),
                         axis=2)
        accept = (((cat[:, None] & msk[None, :]) != 0) & ((cat[None, :] & msk[:, None]) != 0)
                  & ~(st[:, None] & st[None, :]))
        i, j = np.nonzero(np.triu(overlap & accept, k=1))
        return np.stack([keys[i], keys[j]], axis=1).astype(np.uint64)


def as_set(pairs):
    return {(int(a), int(b)) for a, b in pairs}


def sorted_pairs(pairs):
    return np.array(sorted(pairs), np.uint64).reshape(-1, 2)
