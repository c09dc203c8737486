"""Height correction: the planar landmark graph leaves z to the odometry, whose z drifts on
rough ground (a small pitch error integrates into metres of height over a loop). Trees give
the vertical constraint: a tree's breast-height centre is one fixed height, so every
re-observation of it measures the odometry's z error at that keyframe.

Unknowns: a z offset dz_k per keyframe (true z = odometry z + dz_k) and a height h_j per tree.
Factors, all linear: dz_0 = 0 (the output frame is the first scan's); a random walk
dz_k - dz_{k-1} = 0 with sigma `step + per_m * distance` between the keyframes; per observation
h_j - dz_k = z_obs (z_obs: the stem centre's z in the odometry frame) with a Huber kernel by
iteratively reweighted least squares. One sparse solve (SuperLU) per call, cached until new
data arrive; a few ms for thousands of keyframes, so it runs at checkpoints, not per scan.
"""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.linalg import spsolve


class HeightGraph:
    """Collect `add_keyframe` / `add_observation` in order; `solve(n_landmarks)` any time."""

    def __init__(
        self,
        obs_sigma_m: float = 0.1,
        step_sigma_m: float = 0.005,
        sigma_per_m: float = 0.01,
        huber_k: float = 1.345,
        iterations: int = 3,
    ) -> None:
        self.obs_sigma_m = float(obs_sigma_m)
        self.step_sigma_m = float(step_sigma_m)
        self.sigma_per_m = float(sigma_per_m)
        self.huber_k = float(huber_k)
        self.iterations = int(iterations)
        self._step_sigma: list[float] = []  # per keyframe (first: unused)
        self._kf: list[int] = []
        self._lm: list[int] = []
        self._z: list[float] = []
        self._cache: tuple[int, int, int, np.ndarray, np.ndarray] | None = None

    @property
    def n_keyframes(self) -> int:
        return len(self._step_sigma)

    @property
    def n_observations(self) -> int:
        return len(self._z)

    def add_keyframe(self, distance_m: float) -> int:
        """A new keyframe, `distance_m` travelled since the previous one; returns its index."""
        d = float(distance_m) if np.isfinite(distance_m) else 0.0
        self._step_sigma.append(self.step_sigma_m + self.sigma_per_m * abs(d))
        return len(self._step_sigma) - 1

    def truncate(self, n_keyframes: int, n_observations: int | None = None) -> None:
        """Forget keyframes from index n_keyframes on (a keyframe the caller had to drop), and
        the observations from index n_observations on when given."""
        n = max(0, int(n_keyframes))
        del self._step_sigma[n:]
        if n_observations is not None:
            m = max(0, int(n_observations))
            del self._kf[m:], self._lm[m:], self._z[m:]
        keep = [i for i, k in enumerate(self._kf) if k < n]
        if len(keep) != len(self._kf):
            self._kf = [self._kf[i] for i in keep]
            self._lm = [self._lm[i] for i in keep]
            self._z = [self._z[i] for i in keep]
        self._cache = None

    def add_observation(self, keyframe: int, landmark: int, z: float) -> None:
        """Keyframe `keyframe` saw tree `landmark` with its centre at height z (odometry frame)."""
        if np.isfinite(z) and 0 <= keyframe < self.n_keyframes and landmark >= 0:
            self._kf.append(int(keyframe))
            self._lm.append(int(landmark))
            self._z.append(float(z))

    def solve(self, n_landmarks: int) -> tuple[np.ndarray, np.ndarray]:
        """z offsets (K,) per keyframe and tree heights (n_landmarks,) (NaN: never seen)."""
        k = self.n_keyframes
        key = (k, self.n_observations, int(n_landmarks))
        if self._cache is not None and self._cache[:3] == key:
            return self._cache[3].copy(), self._cache[4].copy()
        dz = np.zeros(k)
        h = np.full(int(n_landmarks), np.nan)
        if k and self.n_observations:
            kf = np.asarray(self._kf, dtype=np.int64)
            lm = np.asarray(self._lm, dtype=np.int64)
            z = np.asarray(self._z)
            keep = lm < n_landmarks
            kf, lm, z = kf[keep], lm[keep], z[keep]
            seen, col = np.unique(lm, return_inverse=True)
            if len(seen):
                x = self._solve(k, kf, col, z, len(seen))
                dz, h[seen] = x[:k], x[k:]
        self._cache = (*key, dz, h)
        return dz.copy(), h.copy()

    def _solve(self, k: int, kf: np.ndarray, col: np.ndarray, z: np.ndarray, m: int):
        n_obs = len(z)
        steps = np.arange(1, k)
        # rows: prior on dz_0, k-1 random-walk steps, n_obs tree observations
        rows = np.concatenate(
            [[0], 1 + np.repeat(np.arange(k - 1), 2), k + np.repeat(np.arange(n_obs), 2)]
        )
        cols = np.concatenate(
            [
                [0],
                np.column_stack([steps, steps - 1]).ravel(),
                np.column_stack([k + col, kf]).ravel(),
            ]
        )
        vals = np.concatenate([[1.0], np.tile([1.0, -1.0], k - 1), np.tile([1.0, -1.0], n_obs)])
        a = coo_matrix((vals, (rows, cols)), shape=(k + n_obs, k + m)).tocsr()
        b = np.concatenate([np.zeros(k), z])
        sigma = np.concatenate(
            [[1e-3], np.asarray(self._step_sigma[1:]), np.full(n_obs, self.obs_sigma_m)]
        )
        w = 1.0 / sigma**2
        x = np.zeros(k + m)
        for it in range(max(1, self.iterations)):
            at_w = a.T.multiply(w).tocsr()
            x = spsolve((at_w @ a).tocsc(), at_w @ b)
            if it + 1 == self.iterations:
                break
            r = np.abs(a[k:] @ x - z) / self.obs_sigma_m  # Huber weights on observations
            robust = np.where(r <= self.huber_k, 1.0, self.huber_k / np.maximum(r, 1e-12))
            w = np.concatenate([1.0 / sigma[:k] ** 2, robust / self.obs_sigma_m**2])
        return np.asarray(x).ravel()
