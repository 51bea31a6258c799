"""Score a candidate effect by the residual it removes on time blocks held out from its fitting.

Each recording is cut into contiguous time blocks (blocked K-fold over time: neighbouring
samples of a time series are not independent, so a random split would flatter any fit). For
each held-out block, a small linear correction of the residual r = measured - predicted is
fitted on all OTHER blocks:

    null:       r ~ B0 beta            (operating point and the model's own inputs, re-weighted)
    candidate:  r ~ [B0, E(theta)] beta (plus the effect's feature columns)

with the effect's parameter theta (a lag, a delay, a threshold ...) chosen on the training
blocks only, then both are applied to the held-out block. The score is the fractional
reduction of the held-out mean squared residual, candidate vs null (geometric mean of the
blocks' ratios); its
significance a one-sided paired sign-flip randomisation test over the blocks' MSE reductions
(H0: the feature does not help on unseen data, so each block's improvement is as likely
negative as positive).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from ..errors import BadInputError

#: Held-out blocks: at most MAX_BLOCKS, each at least MIN_BLOCK_S long; fewer than MIN_BLOCKS
#: cannot give a significance test worth its name.
MAX_BLOCKS = 30
MIN_BLOCKS = 8
MIN_BLOCK_S = 1.0
#: Random sign flips of the randomisation test (p resolution 1/(N+1)).
N_FLIPS = 20000
RIDGE = 1e-6


def make_blocks(durations: Sequence[float], what: str) -> list[int]:
    """Blocks per recording (proportional to duration); BadInputError if too short in total."""
    total = float(sum(durations))
    n_total = int(min(MAX_BLOCKS, np.floor(total / MIN_BLOCK_S)))
    if n_total < MIN_BLOCKS:
        raise BadInputError(
            f"{what} recordings too short to hold out time blocks: {total:.2f} s usable in total "
            f"(the time all signals cover), need at least {MIN_BLOCKS * MIN_BLOCK_S:.0f} s "
            f"({MIN_BLOCKS} blocks of {MIN_BLOCK_S:g} s)"
        )
    length = total / n_total
    return [max(1, int(round(d / length))) if d >= MIN_BLOCK_S else 0 for d in durations]


def block_labels(n_samples: Sequence[int], blocks: Sequence[int]) -> np.ndarray:
    """Block index of every sample of the concatenated recordings (-1: in no block)."""
    labels = []
    first = 0
    for n, b in zip(n_samples, blocks, strict=True):
        if b == 0:
            labels.append(np.full(n, -1))
            continue
        labels.append(first + np.minimum((np.arange(n) * b) // max(n, 1), b - 1))
        first += b
    return np.concatenate(labels) if labels else np.zeros(0, dtype=int)


@dataclass
class BlockStats:
    """Per-block normal equations of a column set: fits on any union of blocks are cheap."""

    G: np.ndarray  # (K, m, m)  X^T X per block
    g: np.ndarray  # (K, m)     X^T r per block
    s: np.ndarray  # (K,)       r^T r per block
    n: np.ndarray  # (K,)       samples per block

    @classmethod
    def of(cls, X: np.ndarray, r: np.ndarray, labels: np.ndarray, K: int) -> BlockStats:
        m = X.shape[1]
        G = np.zeros((K, m, m))
        g = np.zeros((K, m))
        s = np.zeros(K)
        n = np.zeros(K)
        for k in range(K):
            sel = labels == k
            Xk, rk = X[sel], r[sel]
            G[k] = Xk.T @ Xk
            g[k] = Xk.T @ rk
            s[k] = float(rk @ rk)
            n[k] = sel.sum()
        return cls(G, g, s, n)

    def fit_without(self, k: int) -> tuple[np.ndarray, float]:
        """beta fitted on all blocks but k, and its training SSE."""
        G = self.G.sum(axis=0) - self.G[k]
        g = self.g.sum(axis=0) - self.g[k]
        s = self.s.sum() - self.s[k]
        lam = RIDGE * (np.trace(G) / max(len(G), 1) + 1e-12)
        beta = np.linalg.solve(G + lam * np.eye(len(G)), g)
        return beta, float(s - 2 * beta @ g + beta @ G @ beta)

    def sse(self, k: int, beta: np.ndarray) -> float:
        return float(self.s[k] - 2 * beta @ self.g[k] + beta @ self.G[k] @ beta)


def _standardise(X: np.ndarray) -> np.ndarray:
    sd = X.std(axis=0)
    mu = X.mean(axis=0)
    const = sd < 1e-12
    out = (X - np.where(const, 0.0, mu)) / np.where(const, 1.0, sd)
    out[:, const] = X[:, const]
    # a constant column other than the intercept carries nothing: keep it (ridge handles it)
    return out


class ScoreJson(TypedDict):
    """``Score.as_dict``: a score as --json and the report carry it."""

    mse_reduction: float
    residual_explained: float
    p_value: float
    blocks: int
    blocks_improved: int
    parameters: dict[str, float]
    heldout_rmse_null_rad_s: float
    heldout_rmse_with_effect_rad_s: float


@dataclass
class Score:
    """A candidate's held-out performance on one data set (measured or reference)."""

    fraction: float  #: 1 - geometric mean over held-out blocks of SSE_candidate / SSE_null
    fraction_of_residual: float  #: 1 - sum SSE_candidate / sum r^2 (of the raw residual)
    null_fraction: float  #: 1 - sum SSE_null / sum r^2 (what re-weighting the model alone gives)
    p_value: float
    blocks: int
    blocks_improved: int
    params: dict[str, float]  #: parameter chosen most often across folds
    params_per_fold: list[dict[str, float]] = field(default_factory=list)
    rmse_null: float = float("nan")
    rmse_candidate: float = float("nan")

    def as_dict(self) -> ScoreJson:
        return {
            "mse_reduction": self.fraction,
            "residual_explained": self.fraction_of_residual,
            "p_value": self.p_value,
            "blocks": self.blocks,
            "blocks_improved": self.blocks_improved,
            "parameters": self.params,
            "heldout_rmse_null_rad_s": self.rmse_null,
            "heldout_rmse_with_effect_rad_s": self.rmse_candidate,
        }


def sign_flip_p(d: np.ndarray, n_flips: int = N_FLIPS, seed: int = 0) -> float:
    """One-sided paired randomisation test of mean(d) > 0 (exact for <= 16 blocks)."""
    d = np.asarray(d, dtype=float)
    obs = float(d.sum())
    K = len(d)
    if K == 0:
        return 1.0
    if K <= 16:
        signs = ((np.arange(2**K)[:, None] >> np.arange(K)) & 1) * 2 - 1
        null = signs @ d
        return float(np.mean(null >= obs - 1e-12 * abs(obs)))
    rng = np.random.default_rng(seed)
    signs = rng.integers(0, 2, size=(n_flips, K)) * 2 - 1
    null = signs @ d
    return float((np.sum(null >= obs - 1e-12 * abs(obs)) + 1) / (n_flips + 1))


def score_candidate(r: np.ndarray, labels: np.ndarray, null_X: np.ndarray,
                    extra_per_param: Sequence[np.ndarray], grid: Sequence[dict[str, float]]) -> Score:
    """Held-out score of a candidate given its columns for every parameter value of its grid."""
    K = int(labels.max()) + 1 if len(labels) else 0
    return score_candidate_groups(r, labels, null_X, extra_per_param, grid, [np.arange(K)])[0]


def score_candidate_groups(r: np.ndarray, labels: np.ndarray, null_X: np.ndarray,
                           extra_per_param: Sequence[np.ndarray], grid: Sequence[dict[str, float]],
                           groups: Sequence[np.ndarray]) -> list[Score]:
    """Held-out scores of a candidate on each group of blocks (e.g. measured, reference).

    The corrections are fitted on all blocks but the held-out one, whatever its group: with the
    measured and the reference recordings pooled, a correction that only re-weights the model
    cannot explain a residual that differs between them, while an effect whose feature differs
    between them (the battery voltage of a discharged pack) can.
    """
    ok = (labels >= 0) & np.isfinite(r) & np.all(np.isfinite(null_X), axis=1)
    for E in extra_per_param:
        ok &= np.all(np.isfinite(E), axis=1)
    r = r[ok]
    labels = labels[ok]
    K = int(labels.max()) + 1 if len(labels) else 0
    B0 = _standardise(null_X[ok])
    null = BlockStats.of(B0, r, labels, K)
    stats = [BlockStats.of(np.column_stack([B0, _standardise(E[ok])]), r, labels, K) for E in extra_per_param]
    sse_null = np.zeros(K)
    sse_cand = np.zeros(K)
    chosen = np.full(K, -1)
    for k in range(K):
        if null.n[k] == 0:
            continue
        beta0, _ = null.fit_without(k)
        sse_null[k] = null.sse(k, beta0)
        best = None
        for j, st in enumerate(stats):
            beta, train_sse = st.fit_without(k)
            if best is None or train_sse < best[0]:
                best = (train_sse, j, beta)
        assert best is not None
        chosen[k] = best[1]
        sse_cand[k] = stats[best[1]].sse(k, best[2])
    out = []
    for grp in groups:
        grp = np.asarray([k for k in grp if 0 <= k < K and null.n[k] > 0], dtype=int)
        n = null.n[grp]
        # per-block log ratio of held-out SSE: scale-free, so one block with a huge residual (a
        # start-up transient) does not decide the test alone; ~0 where the feature is irrelevant
        d = np.log(np.maximum(sse_null[grp], 1e-300) / np.maximum(sse_cand[grp], 1e-300))
        total_r2 = float(null.s[grp].sum())
        # effect size: geometric mean over blocks of the held-out MSE ratio (the same per-block
        # log ratios the test uses), so one block with a huge transient does not decide it either
        frac = float(1.0 - np.exp(-np.mean(d))) if len(d) else 0.0
        ch = chosen[grp]
        ch = ch[ch >= 0]
        counts = np.bincount(ch, minlength=len(grid)) if len(ch) else np.zeros(len(grid), int)
        out.append(Score(
            fraction=float(frac),
            fraction_of_residual=float(1.0 - sse_cand[grp].sum() / total_r2) if total_r2 > 0 else 0.0,
            null_fraction=float(1.0 - sse_null[grp].sum() / total_r2) if total_r2 > 0 else 0.0,
            p_value=sign_flip_p(d),
            blocks=int(len(grp)),
            blocks_improved=int(np.sum(d > 0)),
            params=dict(grid[int(np.argmax(counts))]),
            params_per_fold=[dict(grid[j]) for j in ch],
            rmse_null=float(np.sqrt(sse_null[grp].sum() / n.sum())) if n.sum() else float("nan"),
            rmse_candidate=float(np.sqrt(sse_cand[grp].sum() / n.sum())) if n.sum() else float("nan"),
        ))
    return out


#: Grid points whose SSE differs by less than this share are tied: the first in grid order wins.
#: A parameter the columns cannot see (spin-down's tau_up: its columns keep only the slowing part)
#: gives equal SSEs up to float rounding, and rounding must not pick the value a retrained model
#: then uses (a refactor's 1e-16 change moved a published holdout RMSE 3.91 -> 5.06 rad/s that
#: way). Distinct grid points differ by ~1e-2 relative.
TIE_RELATIVE = 1e-9


def fit_params(r: np.ndarray, null_X: np.ndarray, extra_per_param: Sequence[np.ndarray],
               grid: Sequence[dict[str, float]]) -> dict[str, float]:
    """Parameter value with the least in-sample SSE on all the data (the one the model gets)."""
    ok = np.isfinite(r) & np.all(np.isfinite(null_X), axis=1)
    for E in extra_per_param:
        ok &= np.all(np.isfinite(E), axis=1)
    B0 = _standardise(null_X[ok])
    best = None
    for j, E in enumerate(extra_per_param):
        X = np.column_stack([B0, _standardise(E[ok])])
        G = X.T @ X
        lam = RIDGE * (np.trace(G) / len(G) + 1e-12)
        beta = np.linalg.solve(G + lam * np.eye(len(G)), X.T @ r[ok])
        sse = float(np.sum((r[ok] - X @ beta) ** 2))
        if best is None or sse < best[0] * (1.0 - TIE_RELATIVE):
            best = (sse, j)
    assert best is not None
    return dict(grid[best[1]])
