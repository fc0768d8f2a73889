"""Covariances and Jacobians kept in the structure of a multi-station measurement: never N×N.

A budget's N residuals (lengths; for the network also the points' 3n coordinates) are moved by
sources of three shapes, and every source is one of them:

- **diagonal** — one independent input per residual (the tracer's noise, a sensor's noise per
  reading, a stage visit of one length): a vector e, V ⊃ diag(e²);
- **grouped** — each residual moved by the c inputs of its one group (:class:`Grouped`: the CMM
  point a length goes to, c = 3; a stage visit shared by several lengths, c = 1);
- **low rank** — a few inputs common to many residuals: dense (N, q) (the CMM's scales and
  squarenesses, the air's index, the table's expansion) or :class:`Factored`, a sparse N×k map
  times a dense k×q mix (the error motions: the stations' map times the root of their covariance;
  the CMM's smooth field: the points' map times the root of its correlation).

So V = D + Z_b·Z_bᵀ + Z_g·Z_gᵀ: D diagonal, Z_b the grouped sources over the groups with the most
members (the points: the *block*), Z_g every other column (the *globals*). An estimator's
Jacobian J is sparse (a length touches one station and one dead path). REML, the residual test
and the propagation need

    P = V⁻¹ − V⁻¹J(JᵀV⁻¹J)⁺JᵀV⁻¹   (P = V⁻¹ without J)

which is a function of the mixed-model matrix

    C = XᵀD⁻¹X + Λ,   X = [Z_b, Z_g, J],   Λ = diag(I, I, 0):   P = D⁻¹ − D⁻¹X·C⁻¹·XᵀD⁻¹

(Woodbury). Z_b's columns form one small c×c block of C per group: they are eliminated block by
block, as the network solver eliminates its points, leaving a dense Schur complement S in the
G = q_g + p global columns; the random globals are eliminated next and J's part last, through a
pseudo-inverse (:class:`Restricted`). Cost O(N·(c + G)² + groups·c·G²), memory O(N·(c + G) +
groups·c·G): linear in the readings. A new physical term of a budget is a new source of one of
the three shapes; nothing here changes.

The dense N×N forms these replace are kept in tests/dense_reference.py, against which
tests/test_structured_budget.py checks this module on small networks to 1e-9.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Union

import numpy as np

if TYPE_CHECKING:  # scipy.sparse loads where it is used: at import it costs every command 0.1 s
    import scipy.sparse as sp

CHUNK_ROWS = 4096  # rows taken at once where a row's dense global part is needed (memory CHUNK_ROWS·G)


@dataclass(frozen=True)
class Grouped:
    """F (N × groups·c): residual i moved by ``values[i]`` on the c inputs of its group, columns
    c·group[i] … c·group[i] + c − 1 (group −1: by none)."""

    values: np.ndarray  # (N, c)
    group: np.ndarray  # (N,) int
    groups: int

    @property
    def width(self) -> int:
        return int(self.values.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        return len(self.group), self.groups * self.width

    def sparse(self) -> Any:
        """As a scipy.sparse CSR matrix (c entries a row)."""
        import scipy.sparse as sp

        N, c = self.values.shape
        rows = np.flatnonzero(self.group >= 0)
        cols = (c * self.group[rows])[:, None] + np.arange(c)
        return sp.csr_matrix((self.values[rows].ravel(), (np.repeat(rows, c), cols.ravel())), shape=self.shape)

    def dense(self) -> np.ndarray:
        return np.asarray(self.sparse().toarray())

    def padded(self, extra: int) -> "Grouped":
        """The same inputs over ``extra`` more residuals they do not move."""
        return Grouped(np.vstack([self.values, np.zeros((extra, self.width))]),
                       np.concatenate([self.group, np.full(extra, -1)]), self.groups)


@dataclass(frozen=True)
class Factored:
    """F = rows·mix: a sparse (N × k) map of k intermediate inputs, then a dense (k × q) mix."""

    rows: Any  # scipy.sparse (N, k)
    mix: np.ndarray  # (k, q)

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.rows.shape[0]), int(self.mix.shape[1])

    def dense(self) -> np.ndarray:
        return np.asarray(self.rows @ self.mix)

    def padded(self, extra: int) -> "Factored":
        import scipy.sparse as sp

        return Factored(sp.vstack([self.rows, sp.csr_matrix((extra, self.rows.shape[1]))]).tocsr(), self.mix)


Effect = Union[np.ndarray, Grouped, Factored]


def effect_rows(effect: Effect) -> int:
    return len(effect) if isinstance(effect, np.ndarray) else effect.shape[0]


def dense_effect(effect: Effect) -> np.ndarray:
    """F as a dense array ((N,) for a diagonal source): for tests and small problems only."""
    return np.asarray(effect, float) if isinstance(effect, np.ndarray) else effect.dense()


def padded(effect: Effect, extra: int) -> Effect:
    """The effect over ``extra`` more residuals it does not move (the network's point rows)."""
    if isinstance(effect, np.ndarray):
        e = np.asarray(effect, float)
        return np.concatenate([e, np.zeros(extra)]) if e.ndim == 1 else np.vstack([e, np.zeros((extra, e.shape[1]))])
    return effect.padded(extra)


def scaled(effect: Effect, factor: float) -> Effect:
    if isinstance(effect, np.ndarray):
        return np.asarray(effect, float) * factor
    if isinstance(effect, Grouped):
        return Grouped(effect.values * factor, effect.group, effect.groups)
    return Factored(effect.rows, effect.mix * factor)


def diagonal_of(effect: Effect) -> np.ndarray | None:
    """diag(F·Fᵀ) when F·Fᵀ is diagonal (each input moves one residual), else None."""
    if isinstance(effect, Factored):
        return None
    if isinstance(effect, Grouped):
        members = np.bincount(effect.group[effect.group >= 0], minlength=effect.groups)
        return np.sum(effect.values**2, axis=1) if np.all(members <= 1) else None
    e = np.asarray(effect, float)
    if e.ndim == 1:
        return e**2
    if np.all(np.count_nonzero(e, axis=0) <= 1):
        return np.sum(e**2, axis=1)
    return None


def grouped_of(effect: Effect) -> Grouped | None:
    """The effect as :class:`Grouped` when each residual is moved by at most one input (else None)."""
    if isinstance(effect, Grouped):
        return effect
    if isinstance(effect, Factored) or np.ndim(effect) != 2:
        return None
    e = np.asarray(effect, float)
    nonzero = e != 0
    if e.shape[1] < 2 or np.any(np.sum(nonzero, axis=1) > 1):
        return None
    group = np.where(nonzero.any(axis=1), np.argmax(nonzero, axis=1), -1)
    return Grouped(e[np.arange(len(e)), np.maximum(group, 0)][:, None] * (group >= 0)[:, None], group, e.shape[1])


def sum_of_squares(effect: Effect) -> float:
    """tr(F·Fᵀ)."""
    if isinstance(effect, Grouped):
        return float(np.sum(effect.values[effect.group >= 0] ** 2))
    if isinstance(effect, Factored):
        return float(np.sum((effect.rows.T @ effect.rows).toarray() * (effect.mix @ effect.mix.T)))
    return float(np.sum(np.asarray(effect, float) ** 2))


def times_effect(matrix: np.ndarray, effect: Effect) -> np.ndarray:
    """M·F for a dense M (m × N): m × q (m × N for a diagonal source: M·diag(e))."""
    M = np.asarray(matrix, float)
    if isinstance(effect, Grouped):
        return np.asarray((effect.sparse().T @ M.T).T)
    if isinstance(effect, Factored):
        return np.asarray((effect.rows.T @ M.T).T) @ effect.mix
    e = np.asarray(effect, float)
    return M * e[None, :] if e.ndim == 1 else M @ e


def transposed_times(effect: Effect, vector: np.ndarray) -> np.ndarray:
    """Fᵀ·v (for a diagonal source e∘v)."""
    v = np.asarray(vector, float)
    if isinstance(effect, Grouped):
        return np.asarray(effect.sparse().T @ v)
    if isinstance(effect, Factored):
        return effect.mix.T @ np.asarray(effect.rows.T @ v)
    e = np.asarray(effect, float)
    return e * v if e.ndim == 1 else e.T @ v


def sparse_columns(effect: Effect) -> tuple[Any, np.ndarray | None]:
    """(a sparse N×k map, a dense k×q mix or None for the identity) with map·mix = F, for a 2-D effect."""
    import scipy.sparse as sp

    if isinstance(effect, Factored):
        return sp.csr_matrix(effect.rows), np.asarray(effect.mix, float)
    if isinstance(effect, Grouped):
        return effect.sparse(), None
    return sp.csr_matrix(np.asarray(effect, float)), None


def r_factor(jacobian: Any, chunk_rows: int = CHUNK_ROWS) -> np.ndarray:
    """R (p×p) of J = Q·R from row chunks of a sparse J (tall-skinny QR): J's singular values and
    column space without a dense N×p array."""
    J = jacobian.tocsr()
    N, p = J.shape
    R = np.zeros((0, p))
    for start in range(0, N, chunk_rows):
        R = np.asarray(np.linalg.qr(np.vstack([R, J[start:start + chunk_rows].toarray()]), mode="r"))
    return R[:p] if R.shape[0] >= p else np.vstack([R, np.zeros((p - R.shape[0], p))])


def column_basis(jacobian: Any, R: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """(W, rank): J·W spans J's column space with full rank, W p×rank, the rank as the SVD of J
    counts it (singular values above s₁·max(N, p)·ε) — the rank the residual test's ν subtracts.
    ``R``: J's R factor when already at hand (:func:`r_factor`)."""
    N, p = jacobian.shape
    if p == 0:
        return np.zeros((0, 0)), 0
    _, sv, vt = np.linalg.svd(r_factor(jacobian) if R is None else R)
    rank = int(np.sum(sv > sv[0] * max(N, p) * np.finfo(float).eps)) if sv.size and sv[0] > 0 else 0
    return vt[:rank].T, rank


def pseudo_inverse_gram(R: np.ndarray) -> np.ndarray:
    """(JᵀJ)⁺ from J's R factor (:func:`r_factor`) as R⁺R⁺ᵀ, so that J⁺ = (JᵀJ)⁺Jᵀ keeps the conditioning of J,
    not of JᵀJ."""
    Rp = np.linalg.pinv(R)
    return np.asarray(Rp @ Rp.T)


@dataclass(frozen=True)
class Arrow:
    """A symmetric matrix over (block, global) columns whose block part is block diagonal: ``bb`` (groups,
    c, c), ``bg`` (groups, c, G), ``gg`` (G, G) — the shape of Xᵀ·diag(w)·X (its block rows of F_b
    unscaled: :meth:`Restricted.arrow`) and of a selector of global columns."""

    bb: np.ndarray
    bg: np.ndarray
    gg: np.ndarray


class Restricted:
    """P = V⁻¹ − V⁻¹J(JᵀV⁻¹J)⁺JᵀV⁻¹ for V = diag(d) + Z_b·Z_bᵀ + Z_g·Z_gᵀ, in the mixed-model form of the
    module docstring: the block eliminated group by group, then the random globals (``randoms``: effects),
    then J (``jacobian``, sparse, optionally times ``jacobian_mix``) through a pseudo-inverse — the order
    and the pseudo-inverse of the dense form it replaces.

    The block is given unscaled, Z_b = F_b·diag(s) (``block``: F_b as :class:`Grouped`, ``block_scale``: s,
    one per block column, √θ of its source): the traces REML needs of a source in the block are then taken
    of F_b itself (:meth:`block_products`, :meth:`trace_block`), never as a trace of Z_b divided by θ, which
    a noise-free bench (θ → 0) would underflow."""

    def __init__(self, d: np.ndarray, block: Grouped | None, randoms: list[Effect], jacobian: Any = None,
                 jacobian_mix: np.ndarray | None = None, block_scale: np.ndarray | None = None):
        import scipy.sparse as sp

        self.d = np.asarray(d, float)
        N = len(self.d)
        self.N = N
        self.dinv = 1.0 / self.d
        if block is None:
            block = Grouped(np.zeros((N, 0)), np.full(N, -1), 0)
        self.block = block
        self.c, self.groups = block.width, block.groups
        self.s = np.ones(self.c) if block_scale is None else np.asarray(block_scale, float)
        pieces, mixes = [], []
        for e in randoms:
            rows, mix = sparse_columns(e)
            pieces.append(rows)
            mixes.append(mix if mix is not None else np.eye(rows.shape[1]))
        self.q = sum(m.shape[1] for m in mixes)  # random global columns
        if jacobian is not None:
            Jsp = sp.csr_matrix(jacobian)
            pieces.append(Jsp)
            mixes.append(jacobian_mix if jacobian_mix is not None else np.eye(Jsp.shape[1]))
        self.p = sum(m.shape[1] for m in mixes) - self.q
        self.G = self.q + self.p
        raw = sp.hstack(pieces).tocsr() if pieces else sp.csr_matrix((N, 0))
        identity = all(m.shape[0] == m.shape[1] and np.array_equal(m, np.eye(m.shape[0])) for m in mixes)
        self.raw = raw  # X_g = raw·T (T None: the identity)
        self.T = None if identity else _block_diagonal(mixes)
        self.member = np.flatnonzero(block.group >= 0)
        self._eliminate()

    # ---- X_g and the block's rows -------------------------------------------------------------
    def _g_times(self, y: np.ndarray) -> np.ndarray:
        return np.asarray(self.raw @ (y if self.T is None else self.T @ y))

    def _g_transposed(self, v: np.ndarray) -> np.ndarray:
        u = np.asarray(self.raw.T @ v)
        return u if self.T is None else self.T.T @ u

    def _g_rows(self, start: int, stop: int) -> np.ndarray:
        chunk = self.raw[start:stop]
        return np.asarray(chunk.toarray() if self.T is None else chunk @ self.T)

    def _gram_gg(self, w: np.ndarray) -> np.ndarray:
        K = np.asarray((self.raw.T @ self.raw.multiply(w[:, None]).tocsr()).toarray())
        return K if self.T is None else np.asarray(self.T.T @ K @ self.T)

    def arrow(self, w: np.ndarray) -> Arrow:
        """Xᵀ·diag(w)·X in arrow form, its block part of F_b (unscaled): Σ w·f·fᵀ and Σ w·f·x_gᵀ per group."""
        w = np.asarray(w, float)
        g, u, rows = self.block.group, self.block.values, self.member
        bb = np.zeros((self.groups, self.c, self.c))
        for a in range(self.c):
            for b in range(a, self.c):
                bb[:, a, b] = bb[:, b, a] = np.bincount(g[rows], weights=(w * u[:, a] * u[:, b])[rows], minlength=self.groups)
        bg = np.zeros((self.groups, self.c, self.G))
        if self.c and self.G and len(rows):
            import scipy.sparse as sp

            E = sp.csr_matrix(((w[:, None] * u)[rows].ravel(), (np.repeat(rows, self.c),
                                                                ((self.c * g[rows])[:, None] + np.arange(self.c)).ravel())),
                              shape=(self.N, self.groups * self.c))
            product = E.T @ self.raw
            bg = np.asarray(product.toarray() if self.T is None else product @ self.T).reshape(self.groups, self.c, self.G)
        return Arrow(bb, bg, self._gram_gg(w))

    # ---- the elimination ------------------------------------------------------------------------
    def _eliminate(self) -> None:
        c, q, p, s = self.c, self.q, self.p, self.s
        core = self.arrow(self.dinv)  # C − Λ, the block part of F_b
        self.Nu = core.bb  # F_bᵀD⁻¹F_b per group
        s2 = s * s
        if self.groups and c:
            self.Ainv = np.linalg.inv(np.eye(c) + s[:, None] * core.bb * s[None, :])  # A = I + S·Nu·S
            self.Au = np.linalg.inv(np.eye(c) + core.bb * s2[None, :])  # S⁻¹A⁻¹S, without dividing by s
        else:
            self.Ainv = self.Au = np.zeros((self.groups, c, c))
        self.Bu = np.matmul(self.Au, core.bg)  # S⁻¹·B, B = A⁻¹·C_bg: (groups, c, G)
        self.SAS = s[:, None] * self.Ainv * s[None, :]  # S·A⁻¹·S
        reduction = _group_sum(core.bg * s2[None, :, None], self.Bu) if self.groups and c else np.zeros((self.G, self.G))
        N_gg = core.gg - reduction  # S − Λ_g: the Schur complement without the random globals' I
        N_rr = N_gg[:q, :q]
        S_rr_inv = np.linalg.inv(np.eye(q) + N_rr) if q else np.zeros((0, 0))
        Trj = S_rr_inv @ N_gg[:q, q:]
        Mj = np.linalg.pinv(N_gg[q:, q:] - N_gg[q:, :q] @ Trj) if p else np.zeros((0, 0))
        M = np.zeros((self.G, self.G))
        M[:q, :q] = S_rr_inv + Trj @ Mj @ Trj.T
        M[:q, q:] = -Trj @ Mj
        M[q:, :q] = M[:q, q:].T
        M[q:, q:] = Mj
        self.M = M  # S⁻¹ (the J part a pseudo-inverse)
        # (I − H) over the random globals, without subtracting from I: S_rr⁻¹·N_rr − T·Mj·Tᵀ
        self.IH_rr = S_rr_inv @ N_rr - Trj @ Mj @ Trj.T

    # ---- P and the hat diagonal ---------------------------------------------------------------
    def _solve(self, ub: np.ndarray, ug: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(y_b, y_g) = C⁻¹·(u_b, u_g), u_b and y_b of the unscaled block (u_b = F_bᵀ·v, X·y = F_b·y_b + X_g·y_g)."""
        s2 = self.s * self.s
        yg = self.M @ (ug - np.einsum("iag,ia->g", self.Bu, s2 * ub)) if self.G else np.zeros(0)
        yb = np.einsum("iab,ib->ia", self.SAS, ub)
        if self.G:
            yb = yb - s2 * np.einsum("iag,g->ia", self.Bu, yg)
        return yb, yg

    def _x_times(self, yb: np.ndarray, yg: np.ndarray) -> np.ndarray:
        out = self._g_times(yg) if self.G else np.zeros(self.N)
        if self.c:
            rows = self.member
            out[rows] += np.einsum("ia,ia->i", self.block.values[rows], yb[self.block.group[rows]])
        return out

    def _x_transposed(self, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        ub = np.zeros((self.groups, self.c))
        rows = self.member
        for a in range(self.c):
            ub[:, a] = np.bincount(self.block.group[rows], weights=(self.block.values[:, a] * v)[rows], minlength=self.groups)
        return ub, (self._g_transposed(v) if self.G else np.zeros(0))

    def apply(self, r: np.ndarray) -> np.ndarray:
        """P·r."""
        v = self.dinv * np.asarray(r, float)
        yb, yg = self._solve(*self._x_transposed(v))
        return v - self.dinv * self._x_times(yb, yg)

    def quadratic(self, r: np.ndarray) -> float:
        """rᵀ·P·r."""
        return float(np.asarray(r, float) @ self.apply(r))

    def hat(self) -> np.ndarray:
        """h_i = x_i·C⁻¹·x_iᵀ for each row x_i of X (so that P_ii = 1/d_i − h_i/d_i²)."""
        h = np.zeros(self.N)
        group, values, s2 = self.block.group, self.block.values, self.s * self.s
        for start in range(0, self.N, CHUNK_ROWS):
            stop = min(start + CHUNK_ROWS, self.N)
            g = group[start:stop]
            inside = g >= 0
            f = values[start:stop] * inside[:, None]
            xg = self._g_rows(start, stop) if self.G else np.zeros((stop - start, 0))
            if self.c:
                gi = np.where(inside, g, 0)
                h[start:stop] += np.einsum("ia,iab,ib->i", f, self.SAS[gi], f)
                z = xg - np.einsum("ia,iag->ig", f * s2, self.Bu[gi]) if self.G else xg
            else:
                z = xg
            if self.G:
                h[start:stop] += np.sum((z @ self.M) * z, axis=1)
        return h

    # ---- traces ---------------------------------------------------------------------------------
    def _qk(self, Q: Arrow) -> tuple[np.ndarray, np.ndarray]:
        """With H = C⁻¹ = E + K·M·Kᵀ (E = diag(A⁻¹, 0), K = [B; −I]) and Q of the unscaled block: R_Q, with
        (Q·K)_b = S·R_Q (groups, c, G), and Kᵀ·Q·K (G, G)."""
        s2 = self.s * self.s
        RQ = np.matmul(Q.bb, s2[None, :, None] * self.Bu) - Q.bg
        KQK = _group_sum(self.Bu * s2[None, :, None], RQ) - _group_sum(Q.bg * s2[None, :, None], self.Bu) + Q.gg
        return RQ, KQK

    def trace_hqhq(self, Q1: Arrow, Q2: Arrow) -> float:
        """tr(C⁻¹·Q1·C⁻¹·Q2)."""
        R1, KQ1K = self._qk(Q1)
        R2, KQ2K = self._qk(Q2)
        blocks = float(np.einsum("iab,ibc,icd,ida->", self.SAS, Q1.bb, self.SAS, Q2.bb, optimize=True))
        cross = _group_sum(R1, np.matmul(self.SAS, R2))
        return blocks + 2.0 * float(np.sum(self.M * cross)) + float(np.sum((self.M @ KQ1K) * (self.M @ KQ2K).T))

    def global_selector(self, columns: np.ndarray) -> Arrow:
        gg = np.zeros((self.G, self.G))
        gg[columns, columns] = 1.0
        return Arrow(np.zeros((self.groups, self.c, self.c)), np.zeros((self.groups, self.c, self.G)), gg)

    def trace_block(self, Q: Arrow, columns: np.ndarray) -> float:
        """tr(F_kᵀ·P·W·P·F_k) for the block's source k (its ``columns``) and Q = Xᵀ·D⁻¹W·D⁻¹X (W diagonal):
        P·F_k = D⁻¹X·C⁻¹Λ_k·S⁻¹, so this is tr(C⁻¹Q·C⁻¹·Λ_kS⁻²), taken with A_u = S⁻¹A⁻¹S and B_u = S⁻¹B."""
        RQ, KQK = self._qk(Q)
        Au = self.Au[:, columns, :]  # the rows of A_u for the source: (Λ_k·A_u)
        Bk = self.Bu[:, columns, :]
        blocks = float(np.einsum("ika,iab,ikb->", Au, Q.bb, Au))
        cross = _group_sum(RQ, np.matmul(Au.transpose(0, 2, 1), Bk))
        BtB = _group_sum(Bk, Bk)
        return blocks + 2.0 * float(np.sum(self.M * cross)) + float(np.sum((self.M @ KQK) * (self.M @ BtB).T))

    def block_products(self, k_cols: np.ndarray, l_cols: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """F_kᵀ·P·F_l for two sources of the block as (block diagonal (groups, c_k, c_l), L_k, L_l) with
        F_kᵀPF_l = blockdiag − L_k·M·L_lᵀ: blockdiag = (A_u·N_u)[k, l], L = B_u[k]."""
        AuNu = np.matmul(self.Au, self.Nu)
        return AuNu[:, k_cols][:, :, l_cols], self.Bu[:, k_cols, :], self.Bu[:, l_cols, :]

    def trace_block_complement(self, columns: np.ndarray) -> float:
        """tr(F_kᵀ·P·F_k) for the block's source k."""
        D, L, _ = self.block_products(columns, columns)
        return float(np.einsum("iaa->", D) - np.sum(self.M * _group_sum(L, L)))

    def norm2_block(self, k_cols: np.ndarray, l_cols: np.ndarray) -> float:
        """‖F_kᵀ·P·F_l‖²_F for two sources of the block."""
        D, Lk, Ll = self.block_products(k_cols, l_cols)
        first = float(np.sum(D**2))
        cross = float(np.sum(self.M * _group_sum(Lk, np.matmul(D, Ll))))
        last = float(np.sum((self.M @ _group_sum(Lk, Lk)) * (self.M @ _group_sum(Ll, Ll)).T))
        return first - 2.0 * cross + last

    def norm2_block_global(self, k_cols: np.ndarray, global_cols: np.ndarray, global_scale: float) -> float:
        """‖F_kᵀ·P·F_l‖²_F for a source k of the block and a random global l (Z_l = F_l·``global_scale``):
        F_kᵀPF_l = B_u[k]·M[:, l]/scale."""
        Bk = self.Bu[:, k_cols, :]
        Mg = self.M[:, global_cols]
        return float(np.sum((Mg.T @ _group_sum(Bk, Bk)) * Mg.T)) / global_scale**2

    def global_complement(self, k_cols: np.ndarray, l_cols: np.ndarray) -> np.ndarray:
        """(I − ΛC⁻¹) over two random globals' columns: √θ_k·√θ_l·F_kᵀPF_l."""
        return np.asarray(self.IH_rr[np.ix_(k_cols, l_cols)])


def _group_sum(X: np.ndarray, Y: np.ndarray) -> np.ndarray:
    """Σ over groups of X_iᵀ·Y_i for (groups, c, G) stacks: one matrix product of the stacked rows (BLAS)."""
    rows = X.shape[0] * X.shape[1]
    return np.asarray(X.reshape(rows, X.shape[2]).T @ Y.reshape(rows, Y.shape[2]))


def _block_diagonal(blocks: list[np.ndarray]) -> np.ndarray:
    rows = sum(b.shape[0] for b in blocks)
    cols = sum(b.shape[1] for b in blocks)
    out = np.zeros((rows, cols))
    r = c = 0
    for b in blocks:
        out[r:r + b.shape[0], c:c + b.shape[1]] = b
        r, c = r + b.shape[0], c + b.shape[1]
    return out
