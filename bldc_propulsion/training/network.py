"""The paper's n-H-1 network (tanh hidden layer, linear output), its Jacobian and scaling.

Everything here works on data ALREADY scaled to [-1, 1] (``minmax_*`` below do that scaling,
as MATLAB's ``mapminmax``), because Nguyen-Widrow initialisation and the tanh working range
assume it.

Parameter vector layout (``phi``, length ``N = H*(n+2) + 1``; 126 for the paper's 3-25-1)::

    phi[0      : n*H        ]  W1 (H, n) in COLUMN-MAJOR order: phi[i*H + h] = W1[h, i]
    phi[n*H    : (n+1)*H    ]  b1 (H,)
    phi[(n+1)*H: (n+2)*H    ]  W2 (H,)
    phi[N-1]                   b2

Column-major W1 is MATLAB's ``IW{1,1}(:)`` order, and it makes the Jacobian block of input
``i`` a contiguous run of H columns (H contiguous rows of the transposed buffer the trainer
fills), so the Jacobian is written with one vectorised operation per input.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "n_params",
    "pack",
    "unpack",
    "forward",
    "jacobian",
    "nguyen_widrow",
    "minmax_fit",
    "minmax_apply",
    "minmax_invert",
]


def n_params(n_in: int, n_hidden: int) -> int:
    """Number of adjustable parameters N of an n-H-1 network."""
    return n_hidden * (n_in + 2) + 1


def _check_dims(n_in: int, n_hidden: int) -> None:
    if int(n_in) != n_in or n_in < 1:
        raise ValueError(f"number of inputs must be a positive integer, got {n_in!r}")
    if int(n_hidden) != n_hidden or n_hidden < 1:
        raise ValueError(f"number of hidden units must be a positive integer, got {n_hidden!r}")


def pack(W1: np.ndarray, b1: np.ndarray, W2: np.ndarray, b2: float) -> np.ndarray:
    """Flatten (W1 (H, n), b1 (H,), W2 (H,), b2) into ``phi`` (layout in the module docstring)."""
    W1 = np.asarray(W1, dtype=np.float64)
    if W1.ndim != 2:
        raise ValueError(f"W1 must be 2-D (H, n), got shape {W1.shape}")
    H, n = W1.shape
    b1 = np.asarray(b1, dtype=np.float64).reshape(-1)
    W2 = np.asarray(W2, dtype=np.float64).reshape(-1)
    if b1.shape != (H,) or W2.shape != (H,):
        raise ValueError(f"b1 and W2 must have {H} elements, got {b1.shape} and {W2.shape}")
    b2_arr = np.asarray(b2, dtype=np.float64)
    if b2_arr.size != 1:
        raise ValueError(f"b2 must be a scalar, got shape {b2_arr.shape}")
    phi = np.empty(n_params(n, H))
    phi[: n * H] = W1.ravel(order="F")
    phi[n * H : (n + 1) * H] = b1
    phi[(n + 1) * H : (n + 2) * H] = W2
    phi[-1] = b2_arr.reshape(())
    return phi


def unpack(phi: np.ndarray, n_in: int, n_hidden: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Split ``phi`` into (W1 (H, n), b1 (H,), W2 (H,), b2 float); arrays are copies."""
    _check_dims(n_in, n_hidden)
    phi = np.asarray(phi, dtype=np.float64)
    n, H = int(n_in), int(n_hidden)
    N = n_params(n, H)
    if phi.shape != (N,):
        raise ValueError(f"phi of a {n}-{H}-1 network must have shape ({N},), got {phi.shape}")
    W1 = phi[: n * H].reshape((H, n), order="F").copy()
    b1 = phi[n * H : (n + 1) * H].copy()
    W2 = phi[(n + 1) * H : (n + 2) * H].copy()
    return W1, b1, W2, float(phi[-1])


def _check_inputs(phi: np.ndarray, X: np.ndarray, n_hidden: int) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (patterns, inputs), got shape {X.shape}")
    _check_dims(X.shape[1], n_hidden)
    phi = np.asarray(phi, dtype=np.float64)
    N = n_params(X.shape[1], int(n_hidden))
    if phi.shape != (N,):
        raise ValueError(
            f"phi of a {X.shape[1]}-{n_hidden}-1 network must have shape ({N},), got {phi.shape}"
        )
    return phi, X


# --- Hot-loop kernels -------------------------------------------------------------------------
# They work on TRANSPOSED, pattern-contiguous arrays (inputs Xat (n+1, P), activations
# At (H, P), Jacobian Jt (N, P)): every write is then a contiguous row, and Jt.T is the
# Fortran-ordered (P, N) Jacobian that BLAS consumes without a copy. Measured at P = 62,050,
# filling a C-ordered (P, N) J column block by column block was 4x slower.


def augment_t(X: np.ndarray) -> np.ndarray:
    """[X, 1]^T as a C-contiguous (n+1, P) array: one GEMM then gives W1 x + b1 for all patterns."""
    Xat = np.empty((X.shape[1] + 1, X.shape[0]))
    Xat[:-1] = X.T
    Xat[-1] = 1.0
    return Xat


def hidden_t_into(phi: np.ndarray, Xat: np.ndarray, n_hidden: int, out: np.ndarray) -> np.ndarray:
    """tanh(W1 x + b1) for all patterns into ``out`` (H, P), allocating nothing P-sized."""
    n1 = Xat.shape[0]
    # phi's column-major W1 followed by b1 is [W1 b1]^T in C order: a view, not a copy.
    Wa = phi[: n1 * n_hidden].reshape(n1, n_hidden)
    np.matmul(Wa.T, Xat, out=out)
    np.tanh(out, out=out)
    return out


def output_t(phi: np.ndarray, At: np.ndarray, n_hidden: int, out: np.ndarray | None = None) -> np.ndarray:
    """Linear output W2 . a + b2 (P,) from hidden activations At (H, P)."""
    y = np.matmul(phi[-1 - n_hidden : -1], At, out=out)
    y += phi[-1]
    return y


def jacobian_t_into(phi: np.ndarray, Xat: np.ndarray, At: np.ndarray, n_hidden: int, Jt: np.ndarray) -> None:
    """Write dy/dphi, transposed, into rows ``Jt[:N]`` (C-contiguous, >= N rows, P columns).

    Uses the activations At already computed for ``phi`` (no second tanh). Rows beyond N
    are left alone: the trainer keeps e in row N so one SYRK yields J^T J and J^T e.
    """
    n = Xat.shape[0] - 1
    H = n_hidden
    W2 = phi[-1 - H : -1]
    # delta[h, p] = dy/dz_h = W2[h] (1 - tanh(z_h)^2) is also the b1 block: compute it in place.
    Db = Jt[n * H : (n + 1) * H]
    np.multiply(At, At, out=Db)
    np.subtract(1.0, Db, out=Db)
    Db *= W2[:, None]
    for i in range(n):  # loop over inputs only, never over patterns
        np.multiply(Db, Xat[i], out=Jt[i * H : (i + 1) * H])
    Jt[(n + 1) * H : (n + 2) * H] = At
    Jt[(n + 2) * H] = 1.0


def forward(phi: np.ndarray, X: np.ndarray, n_hidden: int) -> np.ndarray:
    """Network output y (P,) for scaled inputs X (P, n)."""
    phi, X = _check_inputs(phi, X, n_hidden)
    H = int(n_hidden)
    At = hidden_t_into(phi, augment_t(X), H, np.empty((H, X.shape[0])))
    return output_t(phi, At, H)


def jacobian(phi: np.ndarray, X: np.ndarray, n_hidden: int) -> np.ndarray:
    """Analytic Jacobian of the network OUTPUT, J[p, k] = dy_p / dphi_k, shape (P, N).

    The paper's (4) is the Jacobian of the errors e = d - y, so Psi = de/dphi = -J; the
    LM step (3) phi - (mu I + Psi^T Psi)^-1 Psi^T E is then phi + (mu I + J^T J)^-1 J^T e.
    The array is Fortran-ordered (each column contiguous), the layout BLAS wants for J^T J.
    """
    phi, X = _check_inputs(phi, X, n_hidden)
    H = int(n_hidden)
    Xat = augment_t(X)
    At = hidden_t_into(phi, Xat, H, np.empty((H, X.shape[0])))
    Jt = np.empty((n_params(X.shape[1], H), X.shape[0]))  # the only (P, N) allocation
    jacobian_t_into(phi, Xat, At, H, Jt)
    return Jt.T


def nguyen_widrow(n_in: int, n_hidden: int, rng: np.random.Generator) -> np.ndarray:
    """Initial ``phi`` by Nguyen & Widrow (1990), as MATLAB ``initnw`` does for tanh units.

    With inputs in [-1, 1], each hidden unit's weight row has norm beta = 0.7 H^(1/n) in a
    random direction, and the biases are spread evenly over [-beta, beta] (``initnw``'s
    ``linspace``, signed by the first weight) so the units' active regions tile the input
    cube instead of piling up at the origin. The linear output layer is small random
    (uniform in [-1, 1] / sqrt(H)) so the initial output stays within the scaled range.
    """
    _check_dims(n_in, n_hidden)
    n, H = int(n_in), int(n_hidden)
    beta = 0.7 * H ** (1.0 / n)
    direction = rng.standard_normal((H, n))
    norms = np.linalg.norm(direction, axis=1, keepdims=True)
    norms[norms == 0.0] = 1.0  # measure-zero case; keeps the row finite
    W1 = beta * direction / norms
    if H == 1:
        b1 = np.zeros(1)
    else:
        sign = np.where(W1[:, 0] >= 0.0, 1.0, -1.0)
        b1 = beta * np.linspace(-1.0, 1.0, H) * sign
    scale = 1.0 / np.sqrt(H)
    W2 = rng.uniform(-scale, scale, H)
    b2 = float(rng.uniform(-scale, scale))
    return pack(W1, b1, W2, b2)


# --- mapminmax scaling: x_s = 2 (x - min) / (max - min) - 1 ---------------------------------


def _check_range(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    if lo.shape != hi.shape:
        raise ValueError(f"min and max must have the same shape, got {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
        raise ValueError("scaling min/max must be finite")
    bad = np.flatnonzero(np.atleast_1d(hi <= lo))
    if bad.size:
        raise ValueError(
            f"scaling range is empty (max <= min) for column(s) {bad.tolist()}: "
            "a constant input cannot be scaled to [-1, 1]"
        )
    return lo, hi


def minmax_fit(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-column (min, max) of X (P, n) -> two (n,) arrays; of a 1-D X -> two 0-d arrays.

    A constant column raises ValueError: it carries no information and would divide by zero
    (MATLAB silently maps it to -1; here it almost always means a wrong recording or input).
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim not in (1, 2) or X.shape[0] == 0:
        raise ValueError(f"minmax_fit needs a non-empty 1-D or 2-D array, got shape {X.shape}")
    if not np.all(np.isfinite(X)):
        raise ValueError("minmax_fit: data contain NaN or infinity")
    lo = X.min(axis=0)
    hi = X.max(axis=0)
    const = np.flatnonzero(np.atleast_1d(hi == lo))
    if const.size:
        raise ValueError(
            f"minmax_fit: column(s) {const.tolist()} are constant (max == min); "
            "a constant input cannot be scaled to [-1, 1]"
        )
    return lo, hi


def minmax_apply(X: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Scale X to [-1, 1] with a range from ``minmax_fit`` (values outside it map outside +-1)."""
    lo, hi = _check_range(lo, hi)
    X = np.asarray(X, dtype=np.float64)
    return 2.0 * (X - lo) / (hi - lo) - 1.0


def minmax_invert(Y: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Undo ``minmax_apply`` (e.g. network output back to rad/s)."""
    lo, hi = _check_range(lo, hi)
    Y = np.asarray(Y, dtype=np.float64)
    return (Y + 1.0) * 0.5 * (hi - lo) + lo
