"""EDM completion by semidefinite programming and Dattorro's convex iteration (paper eqs. 8-11).

The back end is cvxpy; Clarabel solves by default. The problem is built once per sparsity pattern
(:class:`EDMCompletionSDP`) with cvxpy Parameters for the direction matrix Z, the weighted data and
the distance bounds, so each convex-iteration step re-solves without re-compiling. Data are scaled
internally (squared distances divided by the squared median observed distance), so neither the
result nor the fit weight depends on units.

Notation: D holds *squared* distances, G is the Gram matrix of the centred points (G1 = 0),
K(G) = diag(G)1^T + 1 diag(G)^T - 2G (eq. 6), W the boolean mask of observed pairs.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import cvxpy as cp
import numpy as np
from numpy.typing import ArrayLike

from rangeslam._validation import as_scalar, frozen, shape_str
from rangeslam.errors import InvalidInputError, SolverError
from rangeslam.geometry.edm import gram_to_edm

__all__ = [
    "MAX_FIT_WEIGHT",
    "RANGE_MODELS",
    "EDMCompletion",
    "EDMCompletionSDP",
    "complete_edm",
    "low_rank_direction",
    "random_direction",
]

#: Solver statuses after which G is used. "optimal_inaccurate" is accepted from Clarabel only (its
#: AlmostSolved: for these rank-deficient SDPs the duality gap routinely stalls near 1e-7, and the
#: convex iteration and the refinement after it need G to a few digits); from SCS it usually means
#: the iteration limit, so it is not.
_USABLE = {"CLARABEL": ("optimal", "optimal_inaccurate"), "SCS": ("optimal",)}

#: Used when the primary solver raises or returns an unusable status (documented in complete_edm).
FALLBACK_SOLVER = "SCS"

METHODS = ("convex_iteration", "trace_min", "trace_max")
#: Largest lambda of eq. (10) (``fit_weight``): beyond it the fit's weights swamp the SDP's
#: conditioning (1e307 made SCS fail to allocate with a bare ValueError); 1e20 still
#: solved, and the package's own settings stay below 1e4.
MAX_FIT_WEIGHT = 1e12


@dataclass(frozen=True)
class EDMCompletion:
    """Result of :func:`complete_edm`.

    Attributes:
        gram: (N, N) centred Gram matrix, in the caller's units squared.
        edm: (N, N) completed squared distances K(gram).
        points: (N, dim) points from the ``dim`` largest eigenpairs of ``gram`` (centred).
        eigen_gap: sum of the N - dim smallest eigenvalues of ``gram`` over its trace: 0 means
            the embedding dimension is ``dim`` (the value of program (ii) of eq. 10, normalised).
        gaps: (iterations,) eigen_gap after each SDP solve.
        iterations: SDP solves made.
        converged: eigen_gap fell below the tolerance (always True for the single-solve methods
            trace_min and trace_max, which do not target a rank).
        status: status of the last SDP solve ("optimal" or "optimal_inaccurate").
        solver: the solver that produced the last solve (the fallback is recorded here).
        method: "convex_iteration", "trace_min" or "trace_max".
        range_scale: (G,) for problems with range groups: the estimated scale k of each group's
            ranges (measured range = k * distance + offset); None otherwise.
        range_offset: (G,) likewise, the offset in the caller's units (0 for the "scale" model).
    """

    gram: np.ndarray
    edm: np.ndarray
    points: np.ndarray
    eigen_gap: float
    gaps: np.ndarray
    iterations: int
    converged: bool
    status: str
    solver: str
    method: str
    range_scale: np.ndarray | None = None
    range_offset: np.ndarray | None = None


#: Models of uncalibrated ranges r (measured) against distances d: r = k d ("scale"),
#: r = d + b ("offset"), r = k d + b ("affine"); k, b unknown per range group.
RANGE_MODELS = ("scale", "offset", "affine")


def eigen_gap(gram: np.ndarray, dim: int) -> float:
    """Sum of the N - dim smallest eigenvalues of a PSD matrix over its trace (0 = rank <= dim)."""
    eig = np.linalg.eigvalsh(0.5 * (gram + gram.T))
    total = float(np.sum(np.maximum(eig, 0.0)))
    if total <= 0:
        return 0.0
    return float(np.sum(np.maximum(eig[: len(eig) - dim], 0.0)) / total)


def low_rank_direction(gram: np.ndarray, dim: int) -> np.ndarray:
    """Z of step (ii), eq. (10): projector onto the eigenvectors of the N - dim smallest eigenvalues.

    It is the minimiser of <G, Z> over 0 <= Z <= I, trace Z = N - dim (Fan's theorem), found by
    ``eigh`` instead of another SDP.
    """
    _, vec = np.linalg.eigh(0.5 * (gram + gram.T))
    low = vec[:, : gram.shape[0] - dim]
    return low @ low.T


def random_direction(n: int, dim: int, rng: np.random.Generator) -> np.ndarray:
    """A random feasible Z for step (i): projector onto 1/sqrt(n) and n - dim - 1 random directions.

    The all-ones direction is the null space of every centred Gram matrix, so it is always kept.
    Used to restart a convex iteration that stalled at a wrong low-rank point.
    """
    ones = np.full((n, 1), 1.0 / np.sqrt(n))
    q, _ = np.linalg.qr(np.hstack([ones, rng.standard_normal((n, n - dim - 1))]))
    return q @ q.T


def embed(gram: np.ndarray, dim: int) -> np.ndarray:
    """(N, dim) points whose Gram matrix is the best rank-dim approximation of ``gram``."""
    val, vec = np.linalg.eigh(0.5 * (gram + gram.T))
    top = vec[:, -dim:][:, ::-1] * np.sqrt(np.maximum(val[-dim:][::-1], 0.0))
    return top


class EDMCompletionSDP:
    """Step (i) of the convex iteration, eq. (10) (and eq. 11 with distance bounds), built once.

        minimise   <G, Z> + lambda || W o (D - K(G)) ||_F^2
        subject to G PSD, G 1 = 0, lower_p^2 <= K(G)_p <= upper_p^2 for the bounded pairs p

    The fit runs over each observed unordered pair once with weight w (so lambda here is the
    paper's lambda up to the factor 2 of counting both triangles). Z = I gives trace minimisation,
    Z = -I trace maximisation (bounded by the fit term).

    Args:
        mask: (N, N) boolean, symmetric, True where a distance is observed (diagonal ignored).
        bounded_pairs: optional (P, 2) index pairs whose distances get lower/upper bounds (eq. 11).
        loss: "l2" (the s-stress of eq. 8, squared residuals) or "l1" (absolute residuals: a few
            wrong distances pull the solution less).
        solver: cvxpy solver name; Clarabel by default.
        range_groups: optional (N, N) integer array: -1 for pairs whose data are distances, and a
            group g >= 0 for pairs whose data are uncalibrated ranges (squared, like the rest)
            sharing an unknown model ``range_model``: all pairs of a group have the same scale k
            and offset b. The squared distance ((r - b) / k)^2 = a r^2 - 2 c r + e is linear in
            (a, c, e) = (1, b, b^2) / k^2, so the unknowns enter the SDP as three variables per
            group, with e >= c^2 / a (equality for the true values) as the one convex constraint
            left of the relaxation. Scale needs pairs with distances (-1) to fix the units; an
            offset is the unknown emission time of an acoustic event (times the speed of sound)
            or a radio's range bias.
        range_model: "scale" (a only), "offset" (a = 1) or "affine" (a, c, e), see
            :data:`RANGE_MODELS`.
        solver_options: keyword options for the primary solver, over the defaults (e.g.
            Clarabel's ``static_regularization_constant``, raised from 1e-8 to 1e-7 by default
            for problems with range groups: its KKT solves failed without).
    """

    def __init__(
        self,
        mask: ArrayLike,
        *,
        bounded_pairs: ArrayLike | None = None,
        loss: str = "l2",
        solver: str = "CLARABEL",
        range_groups: ArrayLike | None = None,
        range_model: str = "scale",
        solver_options: dict | None = None,
    ) -> None:
        w = np.array(mask, copy=True)
        if w.dtype != bool or w.ndim != 2 or w.shape[0] != w.shape[1]:
            raise InvalidInputError(
                f"mask must be a square boolean (N, N) array; got dtype {w.dtype}, "
                f"shape {shape_str(w.shape)}"
            )
        if not np.array_equal(w, w.T):
            raise InvalidInputError("mask must be symmetric (a distance is observed both ways)")
        n = w.shape[0]
        pairs = np.argwhere(np.triu(w, 1))
        if len(pairs) == 0:
            raise InvalidInputError("mask observes no pair of distinct points")
        self.n = n
        self.pairs = pairs
        self.mask = w & ~np.eye(n, dtype=bool)  # the observed pattern, diagonal ignored
        self.solver = solver
        self.solver_options = dict(solver_options or {})
        self._gram = cp.Variable((n, n), PSD=True)
        # Z is set symmetric; a plain (n, n) Parameter keeps its own column in the compiled
        # problem (a symmetric one is re-parametrised), which the conic-data path reads
        self._z = cp.Parameter((n, n), name="Z")
        self._w = cp.Parameter(len(pairs), nonneg=True, name="weights")
        self._wd = cp.Parameter(len(pairs), name="weighted_data")
        k_of_g = self._pair_map(pairs) @ cp.vec(self._gram, order="C")  # K(G) on the pairs
        # w * K(G) - w * D: the product of two Parameters is not DPP, so w * D is one Parameter.
        weighted_residual = cp.multiply(self._w, k_of_g) - self._wd
        constraints = [cp.sum(self._gram, axis=1) == 0]
        self.range_model = range_model
        self.group_of_pair = np.full(len(pairs), -1)
        self.n_groups = 0
        if range_groups is not None:
            weighted_residual, more = self._calibration_terms(
                weighted_residual, range_groups, range_model
            )
            constraints += more
        if loss == "l2":
            fit = cp.sum_squares(weighted_residual)  # s-stress, eq. (8)
        elif loss == "l1":
            fit = cp.norm1(weighted_residual)  # robust to sparse wrong ranges
        else:
            raise InvalidInputError(f"loss must be 'l2' or 'l1'; got {loss!r}")
        self.loss = loss
        self.bounded_pairs = np.zeros((0, 2), dtype=int)
        if bounded_pairs is not None:
            bp = np.array(bounded_pairs, dtype=int, copy=True)
            if bp.ndim != 2 or bp.shape[1] != 2 or np.any(bp < 0) or np.any(bp >= n):
                raise InvalidInputError(
                    f"bounded_pairs must be (P, 2) indices into the {n} points; "
                    f"got shape {shape_str(bp.shape)}"
                )
            self.bounded_pairs = bp
            self._lower = cp.Parameter(len(bp), nonneg=True, name="lower_sq")
            self._upper = cp.Parameter(len(bp), nonneg=True, name="upper_sq")
            k_bounded = self._pair_map(bp) @ cp.vec(self._gram, order="C")
            constraints += [k_bounded >= self._lower, k_bounded <= self._upper]
        self._problem = cp.Problem(
            cp.Minimize(cp.sum(cp.multiply(self._z, self._gram)) + fit), constraints
        )
        if not self._problem.is_dpp():  # a programming error: re-solves would re-compile
            raise RuntimeError("the EDM completion problem is not DPP")
        self.scale = 1.0
        self._conic = None  # the conic data of the loaded data (set_data), built on first solve
        # (compiled problem, (x, N^2) how Z enters its conic objective q)
        self._z_to_q = None

    def restart(self) -> None:
        """Forget the last data's solver and conic data (the compiled problem is kept): the next
        solve builds its solver anew, as the first solve of a new problem does, so a problem
        re-used for other data (:func:`rangeslam.solvers.sdp_pool.pooled_sdp`) gives the same
        bits as one built for them, and an idle one holds no solver's memory. (cvxpy keeps the
        solver in the problem's cache, which every solve after the first updates.)"""
        self._conic = None
        cache = getattr(self._problem, "_solver_cache", None)
        if cache is not None:
            cache.clear()

    def _calibration_terms(self, residual, range_groups: ArrayLike, range_model: str):
        """Residual minus the calibrated squared ranges a r^2 - 2 c r + e of each group."""
        if range_model not in RANGE_MODELS:
            raise InvalidInputError(
                f"range_model must be one of {RANGE_MODELS}; got {range_model!r}"
            )
        groups = np.array(range_groups, copy=True)
        n = self.n
        if groups.shape != (n, n) or not np.issubdtype(groups.dtype, np.integer):
            raise InvalidInputError(
                f"range_groups must be an integer ({n}, {n}) array; got dtype {groups.dtype}, "
                f"shape {shape_str(groups.shape)}"
            )
        if not np.array_equal(groups, groups.T) or np.any(groups < -1):
            raise InvalidInputError("range_groups must be symmetric with entries >= -1")
        g = groups[self.pairs[:, 0], self.pairs[:, 1]]
        if not np.any(g >= 0):
            raise InvalidInputError("range_groups marks no observed pair as a range")
        if range_model != "offset" and not np.any(g < 0):
            raise InvalidInputError(
                f"range_model {range_model!r} needs observed pairs with distances (range_groups "
                "-1) to fix the units; every observed pair is an uncalibrated range"
            )
        ids = np.unique(g[g >= 0])
        if not np.array_equal(ids, np.arange(len(ids))):
            raise InvalidInputError(f"range groups must be numbered 0..G-1; got {ids.tolist()}")
        self.group_of_pair = g
        self.n_groups = n_groups = len(ids)
        p = len(g)
        # One-hot (P, G) coefficient Parameters: w r^2, w r and w on the pairs of each group.
        self._c2 = cp.Parameter((p, n_groups), name="w_r2")
        self._c1 = cp.Parameter((p, n_groups), name="w_r")
        self._c0 = cp.Parameter((p, n_groups), nonneg=True, name="w")
        self._a = cp.Variable(n_groups, nonneg=True, name="a")
        self._c = self._e = None
        more = []
        if range_model == "scale":
            return residual - self._c2 @ self._a, more
        self._c = cp.Variable(n_groups, name="c")
        self._e = cp.Variable(n_groups, nonneg=True, name="e")
        calibrated = self._c2 @ self._a - 2 * (self._c1 @ self._c) + self._c0 @ self._e
        more += [cp.quad_over_lin(self._c[k], self._a[k]) <= self._e[k] for k in ids]
        if range_model == "offset":
            more += [self._a == 1]
        return residual - calibrated, more

    def calibration(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(scale k, offset b) per range group from the last solve (b in the caller's units)."""
        if self.n_groups == 0 or self._a.value is None:
            return None
        a = np.maximum(np.asarray(self._a.value, dtype=float), 1e-300)
        k = 1.0 / np.sqrt(a)
        if self._c is None:
            return k, np.zeros_like(k)
        b = np.asarray(self._c.value, dtype=float) / a * self.scale
        return k, b

    def _pair_map(self, pairs: np.ndarray) -> np.ndarray:
        """(P, N^2) matrix taking vec(G) (row-major) to K(G)_ij = G_ii + G_jj - 2 G_ij, eq. (6)."""
        n = self.n
        a = np.zeros((len(pairs), n * n))
        rows = np.arange(len(pairs))
        i, j = pairs[:, 0], pairs[:, 1]
        a[rows, i * n + i] += 1.0
        a[rows, j * n + j] += 1.0
        a[rows, i * n + j] -= 1.0
        a[rows, j * n + i] -= 1.0
        return a

    def set_data(
        self,
        edm_matrix: np.ndarray,
        *,
        fit_weight: float = 10.0,
        weights: np.ndarray | None = None,
        bounds: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> None:
        """Load squared distances (N, N) (only the masked pairs are read) and scale them.

        ``weights`` (N, N), optional, multiplies each pair's residual (e.g. 0 drops an outlier);
        ``bounds`` = (lower, upper) distances (P,) for the bounded pairs, in the caller's units.
        """
        self._conic = None  # the conic data change with the data
        i, j = self.pairs[:, 0], self.pairs[:, 1]
        d = np.asarray(edm_matrix, dtype=float)[i, j]
        w = np.full(len(d), np.sqrt(fit_weight) if self.loss == "l2" else fit_weight)
        if weights is not None:
            wt = np.asarray(weights, dtype=float)
            if wt.shape != (self.n, self.n):
                raise InvalidInputError(
                    f"weights must have shape ({self.n}, {self.n}); got {shape_str(wt.shape)}"
                )
            if not np.all(np.isfinite(wt)) or np.any(wt < 0):
                raise InvalidInputError("weights must be finite and non-negative")
            w = w * wt[i, j]
        used = d[(w > 0) & (d > 0)]  # the scale comes from the pairs that are fitted
        scale = float(np.sqrt(np.median(used))) if used.size else 1.0
        self.scale = scale
        self._w.value = w
        ranged = self.group_of_pair >= 0
        fixed = d / scale**2
        if self.n_groups:
            r = np.sqrt(np.maximum(d, 0.0)) / scale
            onehot = np.zeros((len(d), self.n_groups))
            onehot[np.flatnonzero(ranged), self.group_of_pair[ranged]] = 1.0
            self._c2.value = onehot * (w * r**2)[:, None]
            self._c1.value = onehot * (w * r)[:, None]
            self._c0.value = onehot * w[:, None]
            fixed = np.where(ranged, 0.0, fixed)
        self._wd.value = w * fixed
        p = len(self.bounded_pairs)
        if p == 0 and bounds is not None:
            raise InvalidInputError("bounds were given but the problem has no bounded_pairs")
        if p:
            if bounds is None:
                raise InvalidInputError("bounds are required: the problem was built with pairs")
            lo, hi = (np.asarray(b, dtype=float) for b in bounds)
            if lo.shape != (p,) or hi.shape != (p,):
                raise InvalidInputError(
                    f"bounds must be two arrays of shape ({p},); got {shape_str(lo.shape)} and "
                    f"{shape_str(hi.shape)}"
                )
            if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
                raise InvalidInputError("bounds must be finite (use a large upper bound instead)")
            if np.any(lo < 0) or np.any(lo > hi):
                i = int(np.argmax((lo < 0) | (lo > hi)))
                raise InvalidInputError(
                    f"bounds must satisfy 0 <= lower <= upper; pair {i} has [{lo[i]}, {hi[i]}]"
                )
            self._lower.value = (lo / scale) ** 2
            self._upper.value = (hi / scale) ** 2

    def solve(self, z: np.ndarray) -> tuple[np.ndarray, str, str]:
        """Solve step (i) for direction ``z``; return (G in caller units^2, status, solver).

        The primary solver runs on the conic data compiled once per :meth:`set_data`
        (:meth:`_solve_conic`). Clarabel that fails is tried again with static regularisation
        1e-7 (unless the options set it), then :data:`FALLBACK_SOLVER`; raises
        :class:`SolverError` with the status when neither gives a usable solution.
        """
        self._z.value = 0.5 * (z + z.T)
        statuses = []
        for name, extra in self._attempts():
            label = name + "".join(f" ({k} {v})" for k, v in extra.items())
            options = self._options(name, extra)
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")  # the status is checked below
                    if name == self.solver and not extra:
                        self._solve_conic(options)
                    else:
                        self._problem.solve(solver=name, **options)
            except cp.error.SolverError as exc:
                statuses.append(f"{label}: error ({str(exc).splitlines()[0]})")
                continue
            except MemoryError as exc:
                # the cone's KKT block grows as N^4: a size the machine cannot hold is reported
                raise SolverError(
                    f"EDM completion SDP of {self.n} points ran out of memory",
                    status=f"{label}: out of memory",
                ) from exc
            status = self._problem.status
            if status in _USABLE.get(name, ("optimal",)) and self._gram.value is not None:
                g = self._gram.value
                return 0.5 * (g + g.T) * self.scale**2, status, name
            statuses.append(f"{label}: {status}")
        raise SolverError("EDM completion SDP failed", status="; ".join(statuses))

    def _attempts(self) -> list[tuple[str, dict]]:
        """(solver, extra options) in the order :meth:`solve` tries them."""
        attempts = [(self.solver, {})]
        if (
            self.solver == "CLARABEL"
            and "static_regularization_constant" not in self.solver_options
        ):
            # masked unfoldings with many sparse columns (tracked echoes) made Clarabel's KKT
            # solves fail at its default static regularisation; 1e-7 solved them
            attempts.append((self.solver, {"static_regularization_constant": 1e-7}))
        if self.solver != FALLBACK_SOLVER:
            attempts.append((FALLBACK_SOLVER, {}))
        return attempts

    def _options(self, name: str, extra: dict) -> dict:
        """The options of one attempt: the package's, the caller's for the primary solver,
        then ``extra``. Clarabel's regularisation is always set (its cached solver would keep
        a retry's otherwise)."""
        options = _solver_options(name, self.n_groups > 0)
        if name == self.solver:
            options.update(self.solver_options)
        if name == "CLARABEL":
            options.setdefault("static_regularization_constant", _clarabel_default_regularisation())
        options.update(extra)
        return options

    def _solve_conic(self, options: dict) -> None:
        """Step (i) by the primary solver on conic data compiled once per :meth:`set_data`: only
        the objective's q moves with Z (q = q_data + M vec(Z)), so each solve hands the solver
        its data through cvxpy's solving chain (the solver's cached instance updated with them)
        without applying every Parameter again; the result is unpacked into the problem, as
        ``Problem.solve`` would."""
        if self._conic is None:
            self._conic = self._compile(options)
        data, chain, inverse, q_data = self._conic
        data[cp.settings.C] = q_data + self._z_to_q[1] @ self._z.value.ravel(order="F")
        raw = chain.solve_via_data(self._problem, data, warm_start=True, solver_opts=options)
        self._problem.unpack_results(raw, chain, inverse)

    def _compile(self, options: dict) -> tuple:
        """(conic data, solving chain, inverse data, q without Z) of the loaded data, and how Z
        enters q (its columns of the compiled objective, read again when cvxpy compiled anew:
        a fallback solver's solve replaces the problem's compiled form)."""
        data, chain, inverse = self._problem.get_problem_data(self.solver, solver_opts=options)
        compiled = data[cp.settings.PARAM_PROB]
        if self._z_to_q is None or self._z_to_q[0] is not compiled:
            col = compiled.param_id_to_col[self._z.id]
            self._z_to_q = (compiled, compiled.q[:-1, col : col + self.n * self.n])
        q_data = data[cp.settings.C] - self._z_to_q[1] @ self._z.value.ravel(order="F")
        return data, chain, inverse, q_data


def _clarabel_default_regularisation() -> float:
    """Clarabel's own default static regularisation (its DefaultSettings)."""
    import clarabel

    return float(clarabel.DefaultSettings().static_regularization_constant)


def _solver_options(name: str, calibrated: bool = False) -> dict:
    if name == "CLARABEL":
        options = {"tol_gap_abs": 1e-7, "tol_gap_rel": 1e-7}
        if calibrated:
            # With range-calibration variables Clarabel's KKT solves failed (NumericalError) on
            # most Plaza windows at its default static regularisation 1e-8; 1e-7 solved them all.
            options["static_regularization_constant"] = 1e-7
        return options
    if name == "SCS":
        return {"eps": 1e-7, "max_iters": 20000}
    return {}


@dataclass(frozen=True)
class CompletionOptions:
    """The iteration settings of :func:`complete_edm`, validated once.

    Attributes:
        method: one of :data:`METHODS`.
        dim: embedding dimension d.
        fit_weight: lambda of eq. (10), on data scaled to unit median distance.
        max_iterations: SDP solves of the convex iteration at most.
        tol: eigen-gap tolerance for convergence.
        embedding_rtol: the iteration also stops when the rank-``dim`` part of G (its best
            rank-dim approximation) changed by at most this fraction (Frobenius norm) since the
            previous solve; 0 never.
    """

    method: str
    dim: int
    fit_weight: float
    max_iterations: int
    tol: float
    embedding_rtol: float = 0.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise InvalidInputError(f"method must be one of {METHODS}; got {self.method!r}")
        if not isinstance(self.dim, int | np.integer) or self.dim < 1:
            raise InvalidInputError(f"dim must be a positive integer; got {self.dim!r}")
        as_scalar(
            self.fit_weight, "fit_weight", low=0.0, low_open=True, high=MAX_FIT_WEIGHT,
            expected=f"positive and finite, at most {MAX_FIT_WEIGHT:g}",
        )  # fmt: skip
        if not (isinstance(self.max_iterations, int | np.integer) and self.max_iterations >= 1):
            raise InvalidInputError(
                f"max_iterations must be a positive integer; got {self.max_iterations!r}"
            )
        if not (np.isfinite(self.embedding_rtol) and 0 <= self.embedding_rtol < 1):
            raise InvalidInputError(
                f"embedding_rtol must be in [0, 1); got {self.embedding_rtol!r}"
            )


@dataclass(frozen=True)
class Iterate:
    """One SDP solve of the convex iteration: its eigen gap, G (N, N), solver status, the solver
    used and the range calibration (scale, offset) of that solve (None without range groups)."""

    gap: float
    gram: np.ndarray
    status: str
    solver: str
    calibration: tuple[np.ndarray, np.ndarray] | None


def _completion_problem(mask, problem, **build) -> EDMCompletionSDP:
    """The SDP for ``mask``: built from the ``build`` keywords of :class:`EDMCompletionSDP`, or the
    given ``problem`` checked against the mask (range groups and solver options are fixed at build
    time)."""
    if problem is None:
        return EDMCompletionSDP(mask, **build)
    if build["range_groups"] is not None or build["solver_options"] is not None:
        raise InvalidInputError(
            "range_groups and solver_options are fixed when the problem is built; pass them "
            "there, not with problem"
        )
    if not np.array_equal(
        np.asarray(mask, dtype=bool) & ~np.eye(problem.n, dtype=bool), problem.mask
    ):
        raise InvalidInputError("mask differs from the mask the given problem was built for")
    return problem


def _checked_edm(edm_matrix, problem: EDMCompletionSDP, dim: int) -> np.ndarray:
    """(N, N) float copy of the squared distances, finite and non-negative where observed."""
    n = problem.n
    if dim >= n:
        raise InvalidInputError(f"dim must be smaller than the number of points {n}; got {dim}")
    d = np.array(edm_matrix, dtype=float, copy=True)
    if d.shape != (n, n):
        raise InvalidInputError(f"edm_matrix must have shape ({n}, {n}); got {shape_str(d.shape)}")
    observed = d[problem.pairs[:, 0], problem.pairs[:, 1]]
    if not np.all(np.isfinite(observed)) or np.any(observed < 0):
        raise InvalidInputError("edm_matrix must be finite and non-negative where observed")
    return d


def _start_direction(method: str, z0, n: int) -> np.ndarray:
    """Z (N, N) of the first solve: z0 or I for the convex iteration, +-I for trace min/max."""
    if method == "convex_iteration":
        z = np.eye(n) if z0 is None else np.asarray(z0, dtype=float)
        if z.shape != (n, n):
            raise InvalidInputError(f"z0 must have shape ({n}, {n}); got {shape_str(z.shape)}")
        if not np.all(np.isfinite(z)) or not np.allclose(z, z.T, atol=1e-9):
            raise InvalidInputError("z0 must be a finite symmetric matrix")
        return z
    if z0 is not None:
        raise InvalidInputError(f"z0 is only used by the convex iteration, not {method!r}")
    return np.eye(n) if method == "trace_min" else -np.eye(n)


def _convex_iteration(
    problem: EDMCompletionSDP, z: np.ndarray, options: CompletionOptions
) -> tuple[Iterate, list[float]]:
    """Alternate step (i) (the SDP) and step (ii) (Z from the eigenvectors), eq. (10).

    Stops when the gap is below ``tol``, stalls (no relative progress of 1e-3 over 5
    iterations) or, with ``embedding_rtol``, once the rank-d part of G has settled; returns the
    iterate with the smallest gap and the gap after every solve.
    """
    iterations = options.max_iterations if options.method == "convex_iteration" else 1
    gaps: list[float] = []
    best = top = None
    for _ in range(iterations):
        g, status, used = problem.solve(z)
        gaps.append(eigen_gap(g, options.dim))
        if best is None or gaps[-1] <= best.gap:
            best = Iterate(gaps[-1], g, status, used, problem.calibration())
        if gaps[-1] <= options.tol:
            break
        if len(gaps) > 5 and gaps[-1] > (1 - 1e-3) * min(gaps[:-5]):
            break  # stalled: the last 5 iterations did not improve on the earlier best
        z, previous = low_rank_direction(g, options.dim), top
        top = rank_part(g, options.dim)
        if previous is not None and embedding_settled(previous, top, options.embedding_rtol):
            # the points embed(G) no longer move: the refinement after the SDP (least squares
            # or GTSAM) takes them from here; the remaining gap only sharpens the rank
            break
    return best, gaps


def rank_part(gram: np.ndarray, dim: int) -> np.ndarray:
    """(N, N) the best rank-``dim`` approximation of a symmetric ``gram`` (its top eigenpairs)."""
    points = embed(gram, dim)
    return points @ points.T


def embedding_settled(previous: np.ndarray, current: np.ndarray, rtol: float) -> bool:
    """Whether two rank-d parts (N, N) of successive G differ by at most ``rtol`` of the current
    one's Frobenius norm (never for rtol = 0)."""
    if rtol <= 0:
        return False
    return bool(np.linalg.norm(current - previous) <= rtol * np.linalg.norm(current))


def _completion_result(best: Iterate, gaps: list[float], options: CompletionOptions):
    """The :class:`EDMCompletion` of the best iterate: converged when its gap is below ``tol``
    (always for trace_min and trace_max, which do not target a rank)."""
    converged = options.method != "convex_iteration" or best.gap <= options.tol
    calibration = best.calibration
    return EDMCompletion(
        gram=frozen(best.gram),
        edm=frozen(np.maximum(gram_to_edm(best.gram), 0.0)),
        points=frozen(embed(best.gram, options.dim)),
        eigen_gap=best.gap,
        gaps=frozen(np.array(gaps)),
        iterations=len(gaps),
        converged=bool(converged),
        status=best.status,
        solver=best.solver,
        method=options.method,
        range_scale=None if calibration is None else frozen(calibration[0]),
        range_offset=None if calibration is None else frozen(calibration[1]),
    )


def complete_edm(
    edm_matrix: ArrayLike,
    mask: ArrayLike,
    dim: int,
    *,
    method: str = "convex_iteration",
    fit_weight: float = 10.0,
    max_iterations: int = 50,
    tol: float = 1e-6,
    z0: np.ndarray | None = None,
    weights: np.ndarray | None = None,
    bounded_pairs: ArrayLike | None = None,
    bounds: tuple[ArrayLike, ArrayLike] | None = None,
    loss: str = "l2",
    solver: str = "CLARABEL",
    problem: EDMCompletionSDP | None = None,
    range_groups: ArrayLike | None = None,
    range_model: str = "scale",
    solver_options: dict | None = None,
    embedding_rtol: float = 0.0,
) -> EDMCompletion:
    """Complete a partial EDM with embedding dimension ``dim`` (eq. 8, rank relaxed).

    Args:
        edm_matrix: (N, N) squared distances; only entries where ``mask`` is True are read.
        mask: (N, N) boolean, symmetric, True where observed (W of eq. 8; eq. 9 for MDU).
        dim: embedding dimension d (2 or 3).
        method: "convex_iteration" (eq. 10: from Z = I, i.e. trace minimisation, alternate the SDP
            and Z = projector on the eigenvectors of the N - d smallest eigenvalues, until their
            sum is below ``tol`` times the trace), "trace_min" (one SDP with Z = I) or
            "trace_max" (one SDP with Z = -I).
        fit_weight: lambda of eq. (10), on data scaled to unit median distance; at most
            :data:`MAX_FIT_WEIGHT` (1e12).
        z0: starting direction instead of I (e.g. :func:`random_direction` for a restart).
        weights: optional (N, N) non-negative per-pair weights of the fit (0 drops a pair).
        bounded_pairs, bounds: eq. (11) distance bounds: pairs (P, 2) and (lower, upper) (P,),
            distances with 0 <= lower <= upper.
        loss: "l2" (s-stress, eq. 8) or "l1" (robust to a few wrong distances).
        solver: cvxpy solver; on failure the SDP is retried with SCS (``FALLBACK_SOLVER``) and the
            solver used is recorded in the result. SolverError (with both statuses) if both fail.
        problem: a prebuilt :class:`EDMCompletionSDP` for this mask, to reuse across calls (its
            mask must equal ``mask``; its bounded pairs, loss, solver and range groups are used).
        range_groups, range_model: pairs whose data are uncalibrated ranges, with an unknown
            scale and/or offset per group, estimated with G (see :class:`EDMCompletionSDP`);
            the estimates are returned in ``range_scale`` and ``range_offset``.
        solver_options: options for ``solver`` (see :class:`EDMCompletionSDP`).
        embedding_rtol: also stop the convex iteration once the best rank-``dim`` approximation
            of G moved by at most this fraction (Frobenius norm) between two solves (the points
            have settled; a refinement takes them from there); 0 (default) never.

    The iteration also stops when the gap stops decreasing (no relative progress of 1e-3 over
    5 iterations); ``converged`` then stays False and the iterate with the smallest gap is
    returned. For trace_min and trace_max ``converged`` is True: they do not target a rank.
    """
    options = CompletionOptions(method, dim, fit_weight, max_iterations, tol, embedding_rtol)
    problem = _completion_problem(
        mask,
        problem,
        bounded_pairs=bounded_pairs,
        loss=loss,
        solver=solver,
        range_groups=range_groups,
        range_model=range_model,
        solver_options=solver_options,
    )
    d = _checked_edm(edm_matrix, problem, dim)
    problem.set_data(
        d,
        fit_weight=fit_weight,
        weights=weights,
        bounds=None if bounds is None else (np.asarray(bounds[0]), np.asarray(bounds[1])),
    )
    z = _start_direction(method, z0, problem.n)
    best, gaps = _convex_iteration(problem, z, options)
    return _completion_result(best, gaps, options)
