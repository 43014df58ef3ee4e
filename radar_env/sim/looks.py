"""The packed look layout: the data format the episode drawer writes and the filter kernels read.

A look row ``L_*`` packs the episode data of one look into ``W_LOOK`` float64 columns (flags as 0/1); the look
cursor ``it (B, W_IT)`` (int) holds each row's next look ``I_K`` and its number of looks ``I_N``. Also here: which
looks the two-hit track start uses, a property of the looks that the drawer needs to size an episode.
"""

from __future__ import annotations

import numpy as np

__all__ = ["LOOK_COLUMNS", "W_LOOK", "W_IT", "I_K", "I_N", "init_looks", "looks_for_track_start", "padded_looks"]

# ---------------------------------------------------------------------------------------------- look row layout
L_T, L_SITE, L_RANGE, L_RSTD, L_BSTD, L_RDSTD = 0, 1, 3, 4, 5, 6
L_TRUTH, L_TACC, L_TTURN, L_MAN, L_DET, L_BEAR, L_RDOT, L_Z, L_R = 7, 11, 13, 14, 15, 16, 17, 18, 20
W_LOOK = 24
LOOK_COLUMNS = {  # episode field -> (first column, trailing shape)
    "t_s": (L_T, ()), "site_xy_m": (L_SITE, (2,)), "range_m": (L_RANGE, ()), "range_noise_std_m": (L_RSTD, ()),
    "bearing_noise_std_rad": (L_BSTD, ()), "radial_velocity_noise_std_m_s": (L_RDSTD, ()),
    "truth": (L_TRUTH, (4,)), "truth_accel_m_s2": (L_TACC, (2,)), "truth_turn_rate_rad_s": (L_TTURN, ()),
    "maneuvering": (L_MAN, ()), "detected": (L_DET, ()), "bearing_rad": (L_BEAR, ()),
    "radial_velocity_m_s": (L_RDOT, ()), "z_m": (L_Z, (2,)), "R_m2": (L_R, (2, 2)),
}

# the look cursor: next look to process, looks in the episode (columns of the tracker's int state ``it``)
I_K, I_N = 0, 1
W_IT = 2


def init_looks(detected, t_s):
    """Indices of the two looks used for the two-hit start: the first detection and the next detection at a
    strictly later time. Returns ``(i1, i2)`` or raises ``ValueError`` if there are not two."""
    det = np.flatnonzero(detected)
    if det.size < 2:
        raise ValueError("an episode needs at least two detected looks for the two-hit track start")
    i1 = int(det[0])
    later = det[t_s[det] > t_s[i1]]
    if later.size == 0:
        raise ValueError("an episode needs two detected looks at different times for the two-hit track start")
    return i1, int(later[0])


def looks_for_track_start(detected, t_s, warmup_scans):
    """Number of looks an episode needs so that the track start (two hits, then ``warmup_scans`` warm-up looks)
    leaves at least one look for a policy to act on: index of the second hit + 2 + ``warmup_scans``. ``None`` if
    the episode has no two hits at different times."""
    try:
        _, i2 = init_looks(detected, t_s)
    except ValueError:
        return None
    return i2 + 2 + int(warmup_scans)


def padded_looks(t_s, z_m, R_m2, detected, n_looks, k_start):
    """B padded look sequences as the per-look filter kernels take them: contiguous float64 ``t (B, K)``, ``z (B, K,
    2)`` with NaN as 0, ``R (B, K, 2, 2)`` with the identity where missed, ``det (B, K)`` bool, ``n_looks (B,)`` and
    ``k_start (B,)`` int64 (the first look filtered; ``k_start - 1`` is the start). ``ValueError`` for shapes that
    disagree or ``k_start`` outside ``[1, n_looks]``, ``n_looks`` above K."""
    t = np.ascontiguousarray(t_s, dtype=np.float64)
    B, K = t.shape
    z = np.ascontiguousarray(np.nan_to_num(np.asarray(z_m, dtype=np.float64)))
    det = np.ascontiguousarray(detected, dtype=np.bool_)
    R = np.ascontiguousarray(np.where(det[..., None, None], np.nan_to_num(np.asarray(R_m2, dtype=np.float64)),
                                      np.eye(2)))
    n = np.ascontiguousarray(n_looks, dtype=np.int64).reshape(B)
    ks = np.ascontiguousarray(k_start, dtype=np.int64).reshape(B)
    if z.shape != (B, K, 2) or R.shape != (B, K, 2, 2) or det.shape != (B, K):
        raise ValueError(f"t_s (B, K), z_m (B, K, 2), R_m2 (B, K, 2, 2), detected (B, K) must agree; got "
                         f"{t.shape}, {z.shape}, {R.shape}, {det.shape}")
    if np.any(ks < 1) or np.any(n > K) or np.any(ks > n):
        raise ValueError(f"k_start must be in [1, n_looks] and n_looks <= K = {K}; got k_start {ks}, n_looks {n}")
    return t, z, R, det, n, ks


def range_rate_inputs(shape, radial_velocity_m_s=None, site_xy_m=None, radial_velocity_std_m_s=None,
                      noise_scale=1.0):
    """The per-look range-rate inputs of the filter kernels, for looks of ``shape`` (e.g. ``(B, K)``): contiguous
    float64 ``rdot``, ``var`` (the variance used, ``(noise_scale x std)^2``) and ``site (*shape, 2)``. A look whose
    radial velocity or std is not finite, or whose std is not positive, gets ``var = inf``: its range-rate update is
    the identity (position only). With ``radial_velocity_m_s`` None every look has ``var = inf``."""
    shape = tuple(shape)
    if radial_velocity_m_s is None:
        return np.zeros(shape), np.full(shape, np.inf), np.zeros(shape + (2,))
    if site_xy_m is None or radial_velocity_std_m_s is None:
        raise ValueError("range-rate inputs need site_xy_m and radial_velocity_std_m_s with radial_velocity_m_s")
    rd = np.asarray(radial_velocity_m_s, dtype=np.float64).reshape(shape)
    sd = np.asarray(radial_velocity_std_m_s, dtype=np.float64).reshape(shape) * float(noise_scale)
    ok = np.isfinite(rd) & np.isfinite(sd) & (sd > 0)
    site = np.ascontiguousarray(np.nan_to_num(np.asarray(site_xy_m, dtype=np.float64)).reshape(shape + (2,)))
    return (np.ascontiguousarray(np.where(ok, rd, 0.0)), np.ascontiguousarray(np.where(ok, sd * sd, np.inf)), site)
