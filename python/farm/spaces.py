"""Box and Discrete space descriptors.

Real ``gymnasium.spaces`` when gymnasium can be imported; otherwise small stand-ins with the same
attributes and methods a vector env's user reads (``shape``, ``dtype``, ``low``, ``high``, ``n``,
``sample``, ``contains``, ``seed``). Debian 12 has no gymnasium package, and nothing here needs one.
"""
import numpy as np

try:  # pragma: no cover - taken only where gymnasium is installed
    from gymnasium.spaces import Box, Discrete  # noqa: F401

    GYMNASIUM = True
except ImportError:
    GYMNASIUM = False

    class Box:
        """A box of float32 values: ``low <= x <= high`` per entry, of shape ``shape``."""

        def __init__(self, low, high, shape=None, dtype=np.float32, seed=None):
            self.dtype = np.dtype(dtype)
            self.shape = tuple(shape) if shape is not None else np.shape(low)
            self.low = np.broadcast_to(np.asarray(low, dtype=self.dtype), self.shape).copy()
            self.high = np.broadcast_to(np.asarray(high, dtype=self.dtype), self.shape).copy()
            self.np_random = np.random.default_rng(seed)

        def seed(self, seed=None):
            self.np_random = np.random.default_rng(seed)
            return [seed]

        def sample(self):
            low = np.where(np.isfinite(self.low), self.low, -1.0)
            high = np.where(np.isfinite(self.high), self.high, 1.0)
            return self.np_random.uniform(low, high, self.shape).astype(self.dtype)

        def contains(self, x):
            x = np.asarray(x)
            return x.shape == self.shape and bool(np.all(x >= self.low) and np.all(x <= self.high))

        def __repr__(self):
            return "Box(%s, %s, %s, %s)" % (self.low.min(), self.high.max(), self.shape, self.dtype)

        def __eq__(self, other):
            return (isinstance(other, Box) and self.shape == other.shape and self.dtype == other.dtype
                    and np.array_equal(self.low, other.low) and np.array_equal(self.high, other.high))

    class Discrete:
        """The integers ``0 .. n - 1``."""

        def __init__(self, n, seed=None):
            self.n = int(n)
            self.shape = ()
            self.dtype = np.dtype(np.int64)
            self.np_random = np.random.default_rng(seed)

        def seed(self, seed=None):
            self.np_random = np.random.default_rng(seed)
            return [seed]

        def sample(self):
            return np.int64(self.np_random.integers(self.n))

        def contains(self, x):
            return np.issubdtype(np.asarray(x).dtype, np.integer) and 0 <= int(x) < self.n

        def __repr__(self):
            return "Discrete(%d)" % self.n

        def __eq__(self, other):
            return isinstance(other, Discrete) and self.n == other.n
