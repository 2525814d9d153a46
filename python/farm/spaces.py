"""Box, Discrete and MultiDiscrete space descriptors, and ``batch_space``.

Real ``gymnasium.spaces`` (and ``gymnasium.vector.utils.batch_space``) when gymnasium can be
imported; otherwise small stand-ins with the same attributes and methods a vector env's user reads
(``shape``, ``dtype``, ``low``, ``high``, ``n``, ``nvec``, ``sample``, ``contains``, ``seed``,
``np_random``). Debian 12 has no gymnasium package, and nothing here needs one.
"""
import numpy as np

try:  # pragma: no cover - taken only where gymnasium is installed
    from gymnasium.spaces import Box, Discrete, MultiDiscrete  # noqa: F401
    from gymnasium.vector.utils import batch_space  # noqa: F401

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

    class MultiDiscrete:
        """One integer per entry of ``nvec``: entry ``i`` in ``0 .. nvec[i] - 1`` (a batch of Discrete)."""

        def __init__(self, nvec, dtype=np.int64, seed=None):
            self.nvec = np.asarray(nvec, dtype=dtype)
            self.shape = self.nvec.shape
            self.dtype = np.dtype(dtype)
            self.np_random = np.random.default_rng(seed)

        def seed(self, seed=None):
            self.np_random = np.random.default_rng(seed)
            return [seed]

        def sample(self):
            return self.np_random.integers(self.nvec).astype(self.dtype)

        def contains(self, x):
            x = np.asarray(x)
            return (x.shape == self.shape and np.issubdtype(x.dtype, np.integer)
                    and bool(np.all(x >= 0) and np.all(x < self.nvec)))

        def __repr__(self):
            return "MultiDiscrete(%s)" % self.nvec

        def __eq__(self, other):
            return isinstance(other, MultiDiscrete) and np.array_equal(self.nvec, other.nvec)

    def batch_space(space, n=1):
        """The space of ``n`` stacked samples of ``space``, as Gymnasium's ``batch_space`` makes it:
        a Box gains a leading axis of ``n``; a Discrete becomes ``MultiDiscrete([space.n] * n)``."""
        if isinstance(space, Box):
            low = np.broadcast_to(space.low, (n,) + space.shape)
            high = np.broadcast_to(space.high, (n,) + space.shape)
            return Box(low, high, (n,) + space.shape, space.dtype)
        if isinstance(space, Discrete):
            return MultiDiscrete(np.full(n, space.n), dtype=space.dtype)
        raise TypeError("batch_space: no batch of %r" % (space,))
