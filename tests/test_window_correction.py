"""The window correction (agents.policies.window_correction) and its trainer (agents.training.window): the inputs
by hand, the correction's geometry, batch independence, the loader's checks and a small training run."""

import json
import re
import shutil

import numpy as np
import pytest

from agents.policies import window_correction as wcm
from agents.policies.learned import BUNDLED_LEARNED, load_learned
from agents.training.window import draw_training_looks, input_standardisation, mirrored, training_looks


def _one_look_batch(L=3):
    """One episode of L looks 5 s apart, target flying north at 100 m/s through the origin at the last look."""
    t = np.arange(L) * 5.0
    truth_y = (t - t[-1]) * 100.0
    z = np.stack([np.zeros(L), truth_y], -1)[None]
    R = np.broadcast_to(np.diag([100.0 ** 2, 400.0 ** 2]), (1, L, 2, 2)).copy()
    det = np.ones((1, L), bool)
    x = np.zeros((1, L, 4))
    x[0, :, 1], x[0, :, 3] = truth_y, 100.0
    P = np.broadcast_to(np.diag([50.0 ** 2, 20.0 ** 2, 5.0 ** 2, 3.0 ** 2]), (1, L, 4, 4)).copy()
    return t[None], z, R, det, x, P


# ---- the numpy reference of the compiled inputs
def _frame(x):
    """Unit vector along the estimate's velocity, ``(cos, sin)`` each (B, L); east where the speed is below 1 mm/s."""
    sp = np.hypot(x[..., 2], x[..., 3])
    slow = ~(sp > 1e-3)
    safe = np.where(slow, 1.0, sp)
    return np.where(slow, 1.0, x[..., 2] / safe), np.where(slow, 0.0, x[..., 3] / safe), sp


def _rotated_sd(C, ca, sa, i):
    """Standard deviations along and across ``(ca, sa)`` of the 2x2 block of ``C`` (..., n, n) at ``i``."""
    a = C[..., i, i] * ca ** 2 + 2 * C[..., i, i + 1] * ca * sa + C[..., i + 1, i + 1] * sa ** 2
    c = C[..., i, i] * sa ** 2 - 2 * C[..., i, i + 1] * ca * sa + C[..., i + 1, i + 1] * ca ** 2
    return np.sqrt(np.maximum(a, 0.0)), np.sqrt(np.maximum(c, 0.0))


def _reference_features(t_s, z_m, R_m2, detected, x, P, window_looks, scale_m):
    """The inputs in plain numpy over all (B, L) looks (the first implementation): the independent reference."""
    B, L = t_s.shape
    ca, sa, sp = _frame(x)
    rows = np.arange(L)[None, :]
    feats = []
    R_last = np.zeros((B, L, 2, 2))         # R of the latest detected plot in the window (a missed look has none)
    have = np.zeros((B, L), bool)
    for j in range(int(window_looks)):
        kk = rows - j
        ok = kk >= 0
        kc = np.broadcast_to(np.maximum(kk, 0), (B, L))
        det = np.take_along_axis(detected, kc, 1) & ok
        newest = det & ~have
        R_last[newest] = R_m2[np.nonzero(newest)[0], kc[newest]]
        have |= det
        tau = np.where(ok, np.take_along_axis(t_s, kc, 1) - t_s, 0.0)
        dx = np.take_along_axis(z_m[..., 0], kc, 1) - (x[..., 0] + tau * x[..., 2])
        dy = np.take_along_axis(z_m[..., 1], kc, 1) - (x[..., 1] + tau * x[..., 3])
        al = np.clip((dx * ca + dy * sa) / scale_m, -wcm.RESIDUAL_CLIP, wcm.RESIDUAL_CLIP)
        cr = np.clip((-dx * sa + dy * ca) / scale_m, -wcm.RESIDUAL_CLIP, wcm.RESIDUAL_CLIP)
        feats += [np.where(det, al, 0.0), np.where(det, cr, 0.0), det.astype(np.float64), tau / 60.0]
    Ra, Rc = _rotated_sd(R_last, ca, sa, 0)
    Pa, Pc = _rotated_sd(P, ca, sa, 0)
    Va, Vc = _rotated_sd(P, ca, sa, 2)
    feats += [np.log1p(Ra) / 5, np.log1p(Rc) / 5, sp / scale_m]
    feats += [np.log1p(v) / 5 for v in (Pa, Pc, Va, Vc)]
    F = np.stack(feats, -1)
    F[~np.isfinite(x).all(-1)] = np.nan          # no base estimate, no correction
    return F, ca, sa



def test_compiled_inputs_equal_the_numpy_reference():
    from agents.evaluation.suites import draw_suite
    from radar_env.sim.episode import stack_episodes
    for suite in ("random", "random_radars", "kim_lee_accel"):
        eps = draw_suite(suite, 12, seed=900_000)
        b = stack_episodes(eps)
        run = load_learned("policy_bp").run(eps)
        x = run.x.copy()
        x[3, 20:22, 2:] = 0.0                               # a standing target: the frame falls back to east
        got = wcm.window_features(b.t_s, b.z_m, b.R_m2, b.detected, x, run.P, 12, 300.0)
        want = _reference_features(b.t_s, b.z_m, b.R_m2, b.detected, x, run.P, 12, 300.0)
        fin = np.isfinite(x).all(-1)
        for g, w in zip(got, want):
            assert np.isnan(g[~fin]).all()
            g, w = g[fin], w[fin]
            if g.ndim == 1:                                 # the frame
                np.testing.assert_array_equal(g, w)
                continue
            # the window and the speed exactly; the log1p inputs to the last bit (numpy's vectorised log1p and the C
            # library's, which the compiled code calls, may round differently)
            logs = [48, 49, 51, 52, 53, 54]
            np.testing.assert_array_equal(np.delete(g, logs, 1), np.delete(w, logs, 1))
            np.testing.assert_allclose(g[:, logs], w[:, logs], rtol=1e-15, atol=0)


def test_quadratic_fits_are_least_squares_through_the_detected_plots():
    """fit_looks: each fit equals numpy's least squares through the window's detected residuals (tau in minutes),
    its rms residual with 3 parameters; no fit below 4 detected plots; the other inputs unchanged."""
    from agents.evaluation.suites import draw_suite
    from radar_env.sim.episode import stack_episodes
    fits, K = (4, 8, 12), 12
    o = 4 * K + 7
    checked = 0
    for suite in ("random", "random_radars", "kim_lee_accel"):
        eps = draw_suite(suite, 4, seed=900_000)
        b = stack_episodes(eps)
        run = load_learned("policy_bp").run(eps)
        F = wcm.window_features(b.t_s, b.z_m, b.R_m2, b.detected, run.x, run.P, K, 300.0, fits)[0]
        F0 = wcm.window_features(b.t_s, b.z_m, b.R_m2, b.detected, run.x, run.P, K, 300.0)[0]
        fin = np.isfinite(run.x).all(-1)
        assert F.shape[-1] == wcm.feature_count(K, fits) == o + wcm.FIT_FEATURES * len(fits)
        np.testing.assert_array_equal(F[fin][:, :o], F0[fin])
        for row in F[fin][::5]:
            for f, m in enumerate(fits):
                got = row[o + 9 * f:o + 9 * f + 9]
                det = row[2:4 * m:4] == 1.0
                if det.sum() < 4:
                    assert (got == 0).all()
                    continue
                tau = row[3:4 * m:4][det]
                A = np.stack([np.ones_like(tau), tau, tau ** 2], -1)
                for side in range(2):
                    y = row[side:4 * m:4][det]
                    c = np.linalg.lstsq(A, y, rcond=None)[0]
                    np.testing.assert_allclose(got[3 * side:3 * side + 3], c, rtol=1e-8, atol=1e-10 * np.abs(c).max())
                    r = np.sqrt(((y - A @ c) ** 2).sum() / (det.sum() - 3))
                    np.testing.assert_allclose(got[6 + side], r, rtol=1e-6, atol=1e-12)
                assert got[8] == 1.0
                checked += 1
    assert checked > 100


def test_a_quadratic_fit_by_hand():
    """Plots on a parabola across the track: the fit gives it back exactly, with no residual; a window of fewer than
    4 detected plots gives no fit."""
    K = 6
    t, z, R, det, x, P = _one_look_batch()
    rows, looks = np.array([0]), np.array([2])
    F, _ = wcm.look_features(t, z, R, det, x, P, rows, looks, K, 300.0, (4,))
    assert (F[0, 4 * K + 7:] == 0).all()                      # three looks only: no fit
    # six looks 5 s apart, the track north at 100 m/s: across residuals 300 m x (1 + 2 tau + 3 tau^2), tau in min
    n = 6
    t = np.arange(n, dtype=float)[None] * 5.0
    tau = (t[0] - t[0, -1]) / 60.0
    x = np.zeros((1, n, 4))
    x[0, :, 3] = 100.0
    x[0, :, 1] = 100.0 * t[0]
    z = np.zeros((1, n, 2))
    z[0, :, 1] = 100.0 * t[0]
    z[0, :, 0] = -300.0 * (1 + 2 * tau + 3 * tau ** 2)           # east of a northbound track is across < 0
    R = np.broadcast_to(np.eye(2) * 100.0, (1, n, 2, 2)).copy()
    P = np.broadcast_to(np.eye(4), (1, n, 4, 4)).copy()
    det = np.ones((1, n), bool)
    F, frame = wcm.look_features(t, z, R, det, x, P, np.array([0]), np.array([n - 1]), K, 300.0, (4, 6))
    np.testing.assert_array_equal(frame, [[0.0, 1.0]])
    o = 4 * K + 7
    for f in range(2):
        got = F[0, o + 9 * f:o + 9 * f + 9]
        np.testing.assert_allclose(got[:3], 0, atol=1e-12)                 # along: nothing
        np.testing.assert_allclose(got[3:6], [1, 2, 3], rtol=1e-9)           # across: the parabola
        np.testing.assert_allclose(got[6:], [0, 0, 1], atol=1e-9)


def test_features_by_hand():
    t, z, R, det, x, P = _one_look_batch()
    z[0, 1] += [300.0, 600.0]            # the previous look's plot: 300 m to the right (east), 600 m ahead
    det[0, 0] = False
    F, ca, sa = wcm.window_features(t, z, R, det, x, P, window_looks=4, scale_m=300.0)
    assert F.shape == (1, 3, wcm.feature_count(4)) and (ca[0, -1], sa[0, -1]) == (0.0, 1.0)   # frame: north
    f = F[0, -1]
    # slot 0: the current plot lies on the track; slot 1: 600 m along, 300 m to the right (across is to the left)
    np.testing.assert_allclose(f[0:4], [0, 0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(f[4:8], [2.0, -1.0, 1.0, -5 / 60], atol=1e-12)
    np.testing.assert_allclose(f[8:12], [0, 0, 0, -10 / 60], atol=1e-12)   # not detected: no residual
    np.testing.assert_allclose(f[12:16], [0, 0, 0, 0], atol=1e-12)         # before the episode
    # R and P along the track (north) and across (east)
    np.testing.assert_allclose(f[16:], np.r_[np.log1p([400.0, 100.0]) / 5, 100 / 300,
                                             np.log1p([20.0, 50.0, 3.0, 5.0]) / 5], atol=1e-12)
    # a missed look has no R (NaN in the episodes): R is the latest detected plot's in the window
    R[0, 1] = np.diag([30.0 ** 2, 70.0 ** 2])
    det[0, 2], z[0, 2], R[0, 2] = False, np.nan, np.nan
    f = wcm.window_features(t, z, R, det, x, P, 4, 300.0)[0][0, -1]
    np.testing.assert_allclose(f[16:18], np.log1p([70.0, 30.0]) / 5, atol=1e-12)
    np.testing.assert_allclose(f[0:4], [0, 0, 0, 0], atol=1e-12)
    assert np.isfinite(f).all()
    # no base estimate, no inputs
    x[0, 1] = np.nan
    assert np.isnan(wcm.window_features(t, z, R, det, x, P, 4, 300.0)[0][0, 1]).all()


def test_q_inputs_are_the_base_q_at_the_last_looks():
    """q_looks: log10(max(q, 1e-3)) / 2 of the base's q at looks k, k - 1, ..., after every other input; the floor
    where the base has none (NaN: before its track start) and before the episode; the other inputs unchanged."""
    from agents.evaluation.suites import draw_suite
    from radar_env.sim.episode import stack_episodes
    eps = draw_suite("random_radars", 5, seed=900_000)
    b = stack_episodes(eps)
    run = load_learned("policy_bp").run(eps)
    q = run.q_m_s2.copy()
    q[1, 30] = 1e-7                                         # below the floor
    args = (b.t_s, b.z_m, b.R_m2, b.detected, run.x, run.P, 6, 300.0, (4, 6))
    F0 = wcm.window_features(*args)[0]
    F = wcm.window_features(*args, q, 5)[0]
    assert F.shape[-1] == F0.shape[-1] + 5 == wcm.feature_count(6, (4, 6), 5)
    fin = np.isfinite(run.x).all(-1)
    # not trivially equal: the base's q is finite at every look read, mostly above the floor, and changes from look to
    # look (a q read at the wrong look, or the floor everywhere, would not match)
    qf = q[fin]
    assert np.isfinite(qf).all() and (qf > 1e-3).mean() > 0.9 and np.unique(qf).size > 0.9 * qf.size
    for j in range(1, 5):
        both = fin[:, j:] & np.isfinite(q[:, :-j])
        assert both.sum() > 1000 and (q[:, j:] != q[:, :-j])[both].mean() > 0.9
    np.testing.assert_array_equal(F[fin][:, :-5], F0[fin])
    L = q.shape[1]
    for j in range(5):
        qj = np.full(q.shape, np.nan)
        qj[:, j:] = q[:, :L - j]
        want = np.log10(np.maximum(np.nan_to_num(qj, nan=0.0), 1e-3)) / 2
        np.testing.assert_allclose(F[..., -5 + j][fin], want[fin], rtol=1e-15, atol=0)
    assert F[1, 30, -5] == -1.5 and F[1, 31, -4] == -1.5      # the floor, at the look and one look later
    s = int(run.start_index[0])
    assert np.isnan(q[0, s - 2]) and F[0, s, -3] == -1.5        # two looks back from the start: no q there
    with pytest.raises(ValueError, match="q_looks = 5 needs the base's q"):
        wcm.window_features(*args, None, 5)
    # more q looks than the window (the env wrapper keeps no more) or a q of another shape (read out of its bounds)
    for bad in (7, -1, 2.0, True):
        with pytest.raises(ValueError, match=rf"^q_looks must be an integer in \[0, window_looks = 6\], got {bad!r}$"):
            wcm.window_features(*args, q, bad)
    for short in (q[:, :-1], q[:-1], q[..., None]):
        with pytest.raises(ValueError, match=rf"^q must have t_s's shape \(B, L\) = \(5, {L}\) with q_looks = 5, "
                                             rf"got {re.escape(str(short.shape))}$"):
            wcm.look_features(*args[:6], [4], [L - 1], 6, 300.0, (4, 6), short, 5)
    np.testing.assert_array_equal(wcm.window_features(*args, q[:, :-1], 0)[0], F0)     # not read without q_looks


def test_the_q_inputs_are_documented_as_computed():
    """window.toml and docs/training.md give q_looks' range and the q inputs' formula with the code's floor, and
    CorrectedEstimate's docstring says it keeps the base's q since reset."""
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]

    def flat(text):
        return " ".join(text.replace("#", " ").split())
    assert wcm.Q_FLOOR_M_S2 == 1e-3 and np.log10(wcm.Q_FLOOR_M_S2) / 2 == -1.5
    toml = flat((root / "agents" / "training" / "hyperparams" / "window.toml").read_text())
    entry = toml[toml.index("q_looks an integer"):toml.index("layers widths")]
    for text in ("q_looks an integer in [0, window_looks]", "log10(max(q, 1e-3 m/s^2)) / 2", "-1.5",
                 "current one first"):
        assert text in entry, text
    md = flat((root / "docs" / "training.md").read_text())
    for text in ("(`q_looks`, an integer in [0, `window_looks`], a q-policy base only;",
                 "(`log10(max(q, 1e-3 m/s^2)) / 2`, the floor before its track starts)",
                 "so it must see every step since `reset`"):
        assert text in md, text
    doc = flat(wcm.CorrectedEstimate.__doc__)
    for text in ("It is stateful", 'the history of ``info["q_m_s2"]`` since the last ``reset``',
                 "must therefore see every ``reset`` and ``step``"):
        assert text in doc, text


def test_mirror_flips_every_across_component():
    rng = np.random.default_rng(0)
    F, Y = rng.normal(size=(5, wcm.feature_count(3))), rng.normal(size=(5, 2))
    Fm, Ym = mirrored(F, Y, 3)
    flipped = np.zeros(F.shape[1], bool)
    flipped[[1, 5, 9]] = True
    np.testing.assert_array_equal(Fm[:, flipped], -F[:, flipped])
    np.testing.assert_array_equal(Fm[:, ~flipped], F[:, ~flipped])
    np.testing.assert_array_equal(Ym, Y * [1, -1])
    # with two quadratic fits: their across coefficients too (after 4 x 3 window inputs and 7 others)
    # and the base's q at the last 2 looks after them: a level, the same either side of the track
    F = rng.normal(size=(5, wcm.feature_count(3, (4, 6), 2)))
    assert F.shape[1] == 4 * 3 + 7 + 2 * 9 + 2
    Fm, _ = mirrored(F, Y, 3, fit_looks=(4, 6))
    flipped = np.zeros(F.shape[1], bool)
    flipped[[1, 5, 9, 19 + 3, 19 + 4, 19 + 5, 28 + 3, 28 + 4, 28 + 5]] = True
    np.testing.assert_array_equal(Fm[:, flipped], -F[:, flipped])
    np.testing.assert_array_equal(Fm[:, ~flipped], F[:, ~flipped])


@pytest.mark.parametrize("window, fits, q_looks", [(3, (), 0), (6, (4, 6), 0), (6, (4, 6), 3)])
def test_training_looks_are_the_suites_chunks_then_their_mirror(window, fits, q_looks):
    """draw_training_looks writes its arrays in place: the same looks as each chunk's training_looks, in order,
    then mirrored(); each suite's weight 1 / its mean squared error, normalised to mean 1."""
    from agents.evaluation.suites import draw_suite
    base = load_learned("policy_bp")
    hp = {"scenarios": ["random", "random_radars"], "episodes": 6, "window_looks": window, "scale_m": 300.0,
          "weight_suites": True, "mirror": True, **({"fit_looks": list(fits)} if fits else {}),
          **({"q_looks": q_looks} if q_looks else {})}
    F, Y, V, W = draw_training_looks(base, hp, 11)
    parts = [training_looks(base, draw_suite(n, 6, seed=11), window, 300.0, fits, q_looks) for n in hp["scenarios"]]
    F0, Y0, V0 = (np.concatenate([p[i] for p in parts]) for i in range(3))
    n = len(F0)
    assert F.shape[1] == F0.shape[1] == wcm.feature_count(window, fits, q_looks)
    if q_looks:                 # the q inputs: the base's q, not the floor, and not one value
        Fq = F0[:, -q_looks:]
        assert (Fq > -1.5).mean() > 0.9 and (Fq.std(0) > 0.05).all()
    for a, b in ((F, F0), (Y, Y0), (V, V0)):
        np.testing.assert_array_equal(a[:n], b)
    Fm, Ym, Vm = mirrored(F0, Y0, window, V0, fits)
    for a, b in ((F, Fm), (Y, Ym), (V, Vm)):
        np.testing.assert_array_equal(a[n:], b)
    w = np.concatenate([np.full(len(p[1]), 1.0 / np.mean((p[1] ** 2).sum(-1))) for p in parts])
    np.testing.assert_allclose(W, np.concatenate([w, w]) / w.mean(), rtol=1e-12)
    assert W[:n].mean() == pytest.approx(1.0)


@pytest.mark.parametrize("mirror, standardise", [(True, True), (True, False), (False, True)])
def test_training_batches_are_the_mirrored_standardised_looks_to_the_bit(mirror, standardise):
    """The trainer holds the drawn looks only and makes each batch's mirrored looks (training_batch): its batches,
    and the standardisation over the looks and their mirror, are the rows of the mirrored arrays
    draw_training_looks makes (standardised as numpy does, (F - mean) / sd) to the bit, in the order asked for."""
    from agents.training.window import mirror_signs, training_batch
    base = load_learned("policy_bp")
    hp = {"scenarios": ["random", "random_radars"], "episodes": 4, "window_looks": 6, "scale_m": 300.0,
          "weight_suites": True, "mirror": mirror, "fit_looks": [4, 6], "q_looks": 3}
    F, Y, _, W = draw_training_looks(base, hp, 5)
    Fh, Yh, _, Wh = draw_training_looks(base, hp, 5, with_mirror=False)
    n = len(Fh)
    assert len(F) == (2 * n if mirror else n) and n > 100
    signs = mirror_signs(F.shape[1], 6, (4, 6)) if mirror else None
    if mirror:          # the flipped inputs are the across ones, and a flip is what mirrored() does
        assert 0 < (signs < 0).sum() < len(signs)
        np.testing.assert_array_equal(F[n:], Fh * signs)
    mean, sd = input_standardisation(F) if standardise else (None, None)
    if standardise and mirror:      # the stats of the looks and their mirror, without making the mirror
        np.testing.assert_array_equal(np.stack(input_standardisation(Fh, signs)), np.stack((mean, sd)))
        assert not np.array_equal(input_standardisation(Fh)[0], mean)     # (they are not the drawn looks' own)
    if standardise:
        Fs = F.copy()
        Fs -= mean
        Fs /= sd
    else:
        Fs = F
    idx = np.random.default_rng(0).permutation(len(F))[:300]
    X, Yb, Wb = training_batch(Fh, Yh, Wh, idx, signs, mean, sd)
    for a, b in ((X, Fs[idx]), (Yb, Y[idx]), (Wb, W[idx])):
        np.testing.assert_array_equal(a, b)
    assert (idx >= n).any() == mirror
    np.testing.assert_array_equal(Fh, F[:n])            # the drawn looks themselves are left as they were
    with pytest.raises(ValueError, match=r"signs must be"):
        input_standardisation(Fh, np.ones(3))


def _weights(arch, rng, out_scale=1.0):
    w = {k: rng.normal(scale=0.3, size=s) for k, s in wcm.network_shapes(arch).items()}
    w["out.weight"] = w["out.weight"] * out_scale
    w["out.bias"] = w["out.bias"] * out_scale
    return w


def _save(tmp_path, name="wc", base="policy_bp", out_scale=1.0, window=4, layers=(8, 6), seed=0, q_looks=0):
    arch = {"input_size": wcm.feature_count(window, (), q_looks), "layers": list(layers)}
    w = _weights(arch, np.random.default_rng(seed), out_scale)
    cfg = {"base": base, "window_looks": window, "scale_m": 300.0, "architecture": arch,
           **({"q_looks": q_looks} if q_looks else {})}
    env = json.loads((BUNDLED_LEARNED[base] / "env_config.json").read_text()) if base in BUNDLED_LEARNED else {}
    wcm.save_window_correction(tmp_path / name, w, cfg, env)
    return tmp_path / name


def test_correction_moves_positions_only_by_the_network_in_the_velocity_frame(tmp_path):
    from agents.evaluation.suites import draw_suite
    eps = draw_suite("random", 6, seed=900_000)
    base = load_learned("policy_bp")
    brun = base.run(eps)
    zero = load_learned(_save(tmp_path, "zero", out_scale=0.0))
    assert zero.kind == "window_correction" and zero.policy.is_tracker
    r0 = zero.run(eps)
    np.testing.assert_array_equal(r0.x, brun.x)                   # zero output weights: the base, unchanged
    wc = load_learned(_save(tmp_path))
    r = wc.run(eps)
    assert r.name == "wc" and np.array_equal(r.P, brun.P, equal_nan=True)       # the base's covariance
    np.testing.assert_array_equal(r.x[..., 2:], brun.x[..., 2:])  # velocities untouched
    after = np.arange(r.x.shape[1])[None] >= brun.start_index[:, None]
    np.testing.assert_array_equal(r.x[~after], brun.x[~after])     # before the track start: the base's
    assert np.isfinite(r.x[after & np.isfinite(brun.x).all(-1)]).all()
    # the offset is the network's output rotated from (along, across) of the base velocity into (east, north)
    from radar_env.sim.episode import stack_episodes
    b = stack_episodes(eps)
    F, ca, sa = wcm.window_features(b.t_s, b.z_m, b.R_m2, b.detected, brun.x, brun.P, 4, 300.0)
    i, k = 2, int(brun.start_index[2]) + 5
    o = wcm.network_forward(wc.policy.w, 2, F[i, k][None])[0] * 300.0
    np.testing.assert_allclose(r.x[i, k, :2] - brun.x[i, k, :2],
                               [o[0] * ca[i, k] - o[1] * sa[i, k], o[0] * sa[i, k] + o[1] * ca[i, k]], rtol=1e-12)
    np.testing.assert_allclose(r.extra["correction_m"][i, k], np.hypot(*o), rtol=1e-12)


def test_a_row_alone_equals_the_row_in_a_batch(tmp_path):
    from agents.evaluation.suites import draw_suite
    eps = draw_suite("random_radars", 5, seed=900_000)
    wc = load_learned(_save(tmp_path))
    batch = wc.run(eps)
    # missed looks (no plot, no R) inside tracks: every estimate the base makes stays finite
    assert sum((~e.detected).sum() for e in eps) > 0
    base = load_learned("policy_bp").run(eps)
    assert np.array_equal(np.isfinite(batch.x), np.isfinite(base.x))
    for i in (0, 3):
        alone = wc.run([eps[i]])
        n = alone.x.shape[1]
        assert np.array_equal(alone.x[0], batch.x[i, :n], equal_nan=True)


def test_loader_refuses_each_bad_field_in_one_line(tmp_path):
    d = _save(tmp_path)
    meta = json.loads((d / "policy.json").read_text())
    cases = [({"window_looks": 0}, r"field 'window_looks' must be an integer in \[1, 64\]"),
             ({"scale_m": -1.0}, r"field 'scale_m' must be > 0"),
             ({"architecture": {**meta["architecture"], "input_size": 3}}, r"'architecture.input_size' must be 23"),
             ({"architecture": {**meta["architecture"], "layers": []}}, r"'architecture.layers' must be a list of 1-4"),
             ({"base": "nope"}, r"field 'base' \('nope'\): .*nope: no policy.json naming the base tracker's kind"),
             ({"base": 3}, r"field 'base' must name the base tracker"),
             ({"version": 3}, r"format 'radar-track-window-correction' version 3, need .* version 1 or 2"),
             ({"version": 2}, r"field 'members' must be an integer in \[1, 16\], got None"),
             ({"precision": "float32"}, r"field 'precision' belongs to an ensemble's folder \(version 2\)"),
             ({"fit_looks": [3]}, r"field 'fit_looks' must be a list of at most 8 increasing integers in \[4, "
                                  r"window_looks = 4\], got \[3\]"),
             ({"fit_looks": [4, 4]}, r"field 'fit_looks' must be a list of at most 8 increasing integers"),
             ({"fit_looks": 4}, r"field 'fit_looks' must be a list"),
             ({"fit_looks": [4]}, r"'architecture.input_size' must be 32 for window_looks 4, fit_looks \[4\] and "
                                  r"q_looks 0"),
             ({"q_looks": 5}, r"field 'q_looks' must be an integer in \[0, window_looks = 4\], got 5"),
             ({"q_looks": -1}, r"field 'q_looks' must be an integer in \[0, window_looks = 4\], got -1"),
             ({"q_looks": True}, r"field 'q_looks' must be an integer"),
             ({"q_looks": 2}, r"'architecture.input_size' must be 25 for window_looks 4, fit_looks \[\] and "
                              r"q_looks 2")]
    for change, msg in cases:
        (d / "policy.json").write_text(json.dumps({**meta, **change}))
        with pytest.raises(ValueError, match=msg) as e:
            load_learned(d)
        assert "\n" not in str(e.value)
    # the base's q as inputs: a learned IMM has none; refused in a whole message however long the paths (the base's
    # own errors are cut to 400 characters)
    from agents.policies.layout import Q_POLICY_KINDS
    deep = tmp_path / ("d" * 120) / ("e" * 120)
    deep.mkdir(parents=True)
    imm = _save(deep, "wc_imm_q", base="policy_imm_bp", q_looks=2)
    with pytest.raises(ValueError, match=r"field 'base' \('policy_imm_bp'\): .*kind 'learned_imm_gru' has no q; "
                                         r"q_looks 2 needs a q-policy base \(" + re.escape(", ".join(Q_POLICY_KINDS))
                                         + r"\)$") as e:
        load_learned(imm)
    assert len(str(e.value)) > 400 and str(e.value).startswith(str(imm / "policy.json"))
    # a correction of a correction is refused (its base must be a q-policy or a learned IMM)
    (d / "policy.json").write_text(json.dumps(meta))
    inner = shutil.copytree(d, tmp_path / "outer" / "inner")
    outer = _save(tmp_path / "outer", "wc2", base="inner")
    (outer / "policy.json").write_text(json.dumps({**json.loads((outer / "policy.json").read_text()),
                                                   "base": "../inner"}))
    assert load_learned(inner).kind == "window_correction"
    with pytest.raises(ValueError, match=r"field 'base' \('../inner'\): .*kind 'window_correction'"):
        load_learned(outer)
    # weights of another shape
    w = dict(np.load(d / "policy.npz"))
    w["layer.0.weight"] = w["layer.0.weight"][:, :-1]
    np.savez(d / "policy.npz", **w)
    with pytest.raises(ValueError, match=r"weight 'layer.0.weight' must be float64 of shape \(8, 23\)"):
        load_learned(d)


def test_a_correction_built_by_hand_checks_its_q_looks(tmp_path):
    """WindowCorrection itself (as the trainer builds it, without the loader) refuses a q_looks outside [0,
    window_looks]: past the window, the evaluation and the env wrapper (which keeps window_looks looks) would differ."""
    d = _save(tmp_path, q_looks=2)
    wc = load_learned(d).policy
    w, config = dict(np.load(d / "policy.npz")), json.loads((d / "policy.json").read_text())
    assert wcm.WindowCorrection(w, config, wc.base, wc.cfg).q_looks == 2
    for bad in (5, -1, "2"):
        with pytest.raises(ValueError, match=rf"^q_looks must be an integer in \[0, window_looks = 4\], got {bad!r}$"):
            wcm.WindowCorrection(w, {**config, "q_looks": bad}, wc.base, wc.cfg)
    # and a network whose first layer does not read the inputs those make (q_looks 1: one input fewer)
    with pytest.raises(ValueError, match=r"^architecture.input_size must be 24 \(window_looks 4, fit_looks \[\], "
                                         r"q_looks 1\), got 25$"):
        wcm.WindowCorrection(w, {**config, "q_looks": 1}, wc.base, wc.cfg)


def test_add_covariance_checks_the_runs_inputs_before_drawing_flights(tmp_path):
    """add_covariance draws the training looks from the run's config.json: its window_looks, fit_looks and q_looks
    must be the saved network's (policy.json's, architecture.input_size inputs), its q_looks needs a q-policy base;
    refused in one line before any flight is drawn (this config.json has no flight keys: drawing would fail)."""
    from agents.training.window import add_covariance
    run = _save(tmp_path, "run", q_looks=2)                 # window_looks 4, no fits, q_looks 2: 25 inputs
    meta = json.loads((run / "policy.json").read_text())
    good = {"method": "window", "base": "policy_bp", "window_looks": 4, "fit_looks": [], "q_looks": 2, "seed": 0}
    ins = r"policy.json's window_looks 4, fit_looks \[\], q_looks 2 and architecture.input_size 25 must be "
    cases = [({"q_looks": 0}, {}, ins + r"config.json's window_looks 4, fit_looks \[\], q_looks 0 and their 23 inputs"),
             ({"window_looks": 6}, {}, ins + r"config.json's window_looks 6, fit_looks \[\], q_looks 2 and their 33"),
             ({"fit_looks": [4]}, {}, ins + r"config.json's window_looks 4, fit_looks \[4\], q_looks 2 and their 34"),
             ({}, {"architecture": {**meta["architecture"], "input_size": 23}},
              r"architecture.input_size 23 must be config.json's window_looks 4, fit_looks \[\], q_looks 2 and "
              r"their 25 inputs"),
             ({"q_looks": 5}, {}, r"config.json's q_looks must be an integer in \[0, window_looks = 4\], got 5"),
             ({"base": "policy_imm_bp"}, {}, r"config.json's q_looks 2 needs a q-policy base \(the base's q as "
                                            r"inputs\); its base 'policy_imm_bp' is a learned_imm_gru$")]
    for change, meta_change, msg in cases:
        (run / "config.json").write_text(json.dumps({**good, **change}))
        (run / "policy.json").write_text(json.dumps({**meta, **meta_change}))
        with pytest.raises(ValueError, match=msg) as e:
            add_covariance(run, 1, verbose=0)
        assert str(e.value).startswith(f"--add-covariance {run}") and "\n" not in str(e.value)
    assert not (run / "covariance.json").exists()


def test_input_standardisation_is_numpys_mean_and_sd_to_the_bit():
    """The trainer's streaming mean and sd (no temporary of the looks' size) equal numpy's F.mean(0), F.std(0) bit
    for bit, on real training looks (a run's numbers do not depend on which computed them) and on inputs of very
    different scales."""
    base = load_learned("policy_bp")
    hp = {"scenarios": ["random", "random_radars"], "episodes": 20, "window_looks": 12, "scale_m": 300.0,
          "weight_suites": True, "mirror": True, "fit_looks": [4, 12], "q_looks": 6}
    F = draw_training_looks(base, hp, 17)[0]
    rng = np.random.default_rng(4)
    G = rng.normal(size=(30_001, 9)) * rng.lognormal(0.0, 4.0, 9) + rng.normal(size=9) * 1e3
    for X in (F, G):
        mean, sd = input_standardisation(X)
        np.testing.assert_array_equal(mean, X.mean(0))
        s = X.std(0)
        np.testing.assert_array_equal(sd, np.where(s > 1e-6, s, 1.0))
    # the 6 q columns are there (the last ones), vary (their sd is theirs, not the 1 of a constant input) and are
    # standardised by numpy's mean and sd of those columns
    assert F.shape[1] == wcm.feature_count(12, (4, 12), 6)
    mean, sd = input_standardisation(F)
    Fq = F[:, -6:].copy()
    assert (Fq > -1.5).mean() > 0.9 and (Fq.std(0) > 0.05).all()
    np.testing.assert_array_equal(mean[-6:], Fq.mean(0))
    np.testing.assert_array_equal(sd[-6:], Fq.std(0))
    # numpy sums a single column, or a Fortran-ordered array's columns, pairwise (other bits than the compiled
    # row-by-row sums: shown here): such arrays, and any but a C-ordered float64 (n, m >= 2) one, are refused
    from agents.training.window import _mean_sd
    assert not np.array_equal(_mean_sd(G[:, :1].copy(), np.ones(1), False)[1], G[:, :1].std(0))
    for bad, desc in ((G[:, :1].copy(), r"float64 C-ordered array of shape \(30001, 1\)"),
                      (np.asfortranarray(G), r"float64 not C-ordered array of shape \(30001, 9\)"),
                      (G[:, ::2], r"float64 not C-ordered array of shape \(30001, 5\)"),
                      (G.astype(np.float32), r"float32 C-ordered array of shape \(30001, 9\)"),
                      (G[:0], r"float64 C-ordered array of shape \(0, 9\)"),
                      (G[:, 0].copy(), r"float64 C-ordered array of shape \(30001,\)"),
                      (G.tolist(), "list")):
        with pytest.raises(ValueError, match=r"^F must be a C-ordered float64 array \(n >= 1, m >= 2\) \(numpy's "
                                             rf"mean and sd to the bit\), got a {desc}$"):
            input_standardisation(bad)


def test_standardisation_folded_into_the_first_layer_reads_raw_inputs():
    import torch
    from agents.training.window import _net, _weights
    rng = np.random.default_rng(3)
    F = rng.normal(size=(300, 11)) * rng.uniform(0.1, 20.0, 11) + rng.normal(size=11) * 5
    F[:, 4] = 1.0                                   # a constant input (a suite without misses) keeps sd 1
    mean, sd = input_standardisation(F)
    assert sd[4] == 1.0 and np.allclose(((F - mean) / sd)[:, [0, 5]].std(0), 1.0)
    torch.manual_seed(0)
    net = _net(torch, 11, [7, 5])
    with torch.no_grad():
        net[-1].weight.mul_(100.0)                  # outputs of order 1, not 0.01
        want = net(torch.from_numpy((F - mean) / sd)).numpy()
    got = wcm.network_forward(wcm.layer_weights(_weights(net, [7, 5], mean, sd)), 2, F)
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-12)
    assert np.abs(want).max() > 0.1


def test_training_run_is_reproducible_and_loadable(tmp_path):
    from agents.training.train import main
    args = ["--method", "window", "--seed", "1000", "--out", str(tmp_path), "--quiet", "--hp", "base=policy_bp",
            "--hp", "episodes=12", "--hp", "epochs=2", "--hp", "eval_every=1", "--hp", "layers=[6]",
            "--hp", 'eval_scenarios={"random": 4}', "--hp", 'select_on=["random"]', "--hp", "batch_looks=256"]
    a = main(args + ["--name", "a"])
    b = main(args + ["--name", "b"])
    assert (a / "policy.npz").read_bytes() == (b / "policy.npz").read_bytes()      # same seed, same weights
    lt = load_learned(a / "best")
    assert lt.kind == "window_correction" and lt.name == "a_best"
    summary = json.loads((a / "summary.json").read_text())
    assert [r["epoch"] for r in summary["selection_history"]] == [1, 2]
    assert json.loads((a / "choice.json").read_text())["chosen"] == "final"
    # the recipe's covariance head: fitted for the final and the best weights, reported by the loaded tracker
    assert lt.policy.has_covariance and load_learned(a).policy.has_covariance
    cov = json.loads((a / "best" / "covariance.json").read_text())
    assert cov["epochs"] == 10 and np.isfinite(cov["anees_training"])
    assert summary["covariance"]["best"]["anees_training"] == cov["anees_training"]
    assert sorted(summary["covariance"]) == sorted(["best", a.name])      # the run's name, not <name>.partial
    # --add-covariance on the same run trained without one: the same head (the same flights, the same fit)
    nc = main(args + ["--name", "nocov", "--hp", "covariance_epochs=0"])
    assert not load_learned(nc).policy.has_covariance and not (nc / "covariance.json").exists()
    assert main(["--method", "window", "--add-covariance", str(nc), "--quiet"]) == nc
    for f in ("policy.npz", "best/policy.npz", "policy.json"):
        assert (nc / f).read_bytes() == (a / f).read_bytes(), f
    ncs = json.loads((nc / "summary.json").read_text())        # its records say so, keyed as training keys them
    assert sorted(ncs["covariance"]) == sorted(["best", nc.name])
    assert ncs["covariance"]["best"]["anees_training"] == cov["anees_training"]
    for f in (nc, nc / "best"):
        assert json.loads((f / "training.json").read_text())["summary"]["covariance"] == ncs["covariance"]
    with pytest.raises(SystemExit, match=r"already has a covariance head"):
        main(["--method", "window", "--add-covariance", str(nc), "--quiet"])
    with pytest.raises(SystemExit, match=r"--add-covariance .*: no config.json"):
        main(["--method", "window", "--add-covariance", str(tmp_path), "--quiet"])
    with pytest.raises(SystemExit, match=r"--add-covariance applies to --method window"):
        main(["--method", "ppo", "--algo", "ppo", "--add-covariance", str(nc)])
    # quadratic fits among the inputs: saved in policy.json, read back by the loader
    f = main(args + ["--name", "fits", "--hp", "fit_looks=[4, 12]", "--hp", "covariance_epochs=0"])
    assert json.loads((f / "best" / "policy.json").read_text())["fit_looks"] == [4, 12]
    assert load_learned(f / "best").policy.fit_looks == (4, 12)
    from agents.training.runs import load_hyperparams
    for key in ("fit_looks", "q_looks"):        # the bundled recipe's, as window.toml gives them
        assert json.loads((a / "policy.json").read_text()).get(key, 0) == (load_hyperparams("window")[key] or 0)
    # the first recipe's plain inputs, pooled loss and no fits or q still train, to other weights
    c = main(args + ["--name", "plain", "--hp", "standardise_inputs=false", "--hp", "weight_suites=false",
                     "--hp", "fit_looks=[]", "--hp", "q_looks=0"])
    assert load_learned(c).kind == "window_correction"
    assert "fit_looks" not in json.loads((c / "policy.json").read_text())      # none: the old format
    assert "q_looks" not in json.loads((c / "policy.json").read_text())
    # the base's q as inputs: saved, read back; refused over a base without q
    qr = main(args + ["--name", "q", "--hp", "q_looks=3", "--hp", "covariance_epochs=0"])
    assert json.loads((qr / "best" / "policy.json").read_text())["q_looks"] == 3
    assert load_learned(qr / "best").policy.q_looks == 3
    with pytest.raises(SystemExit, match=r"--hp q_looks: 3 needs a q-policy base .*learned_imm_gru"):
        main(args + ["--name", "q2", "--hp", "q_looks=3", "--hp", "base=policy_imm_bp"])
    with pytest.raises(SystemExit, match=r"--hp q_looks must be an integer in \[0, window_looks = 24\], got 25"):
        main(args + ["--name", "q2", "--hp", "q_looks=25"])
    assert (c / "policy.npz").read_bytes() != (a / "policy.npz").read_bytes()
    for bad, msg in ((["--hp", "layers=[0]"], r"--hp layers: must be a list of 1-4 integer widths"),
                     (["--hp", "scenarios=[\"bizup2002\"]"], r"--hp scenarios: a list of distinct training"),
                     (["--hp", "weight_suites=1"], r"--hp weight_suites: must be true or false, got 1"),
                     (["--hp", "fit_looks=[2]"], r"--hp fit_looks must be a list of at most 8 increasing integers in "
                                                 r"\[4, window_looks = 24\], got \[2\]"),
                     (["--hp", "standardise_inputs=\"yes\""], r"--hp standardise_inputs: must be true or false"),
                     (["--tracker", "cv"], r"--tracker does not apply to --method window"),
                     (["--seed", "899995"], r"--seed: the training flights' seeds 899995..900006 must lie")):
        with pytest.raises(SystemExit, match=msg):
            main(args + ["--name", "c"] + bad)
    assert not (tmp_path / "c").exists() and not (tmp_path / "c.partial").exists()


def test_fresh_flights_draw_new_seeds_and_the_head_fits_the_last_draw(tmp_path):
    from agents.training.train import main
    from agents.training.window import flight_draws
    assert flight_draws({"episodes": 12, "epochs": 5, "fresh_flights_every": 0}, 7) == [7]
    assert flight_draws({"episodes": 12, "epochs": 5, "fresh_flights_every": 2}, 7) == [7, 19, 31]
    assert flight_draws({"episodes": 12, "epochs": 4, "fresh_flights_every": 2}, 7) == [7, 19]
    args = ["--method", "window", "--seed", "1000", "--out", str(tmp_path), "--quiet", "--hp", "base=policy_bp",
            "--hp", "episodes=12", "--hp", "epochs=2", "--hp", "eval_every=1", "--hp", "layers=[6]",
            "--hp", 'eval_scenarios={"random": 4}', "--hp", 'select_on=["random"]', "--hp", "batch_looks=256"]
    same = main(args + ["--name", "same"])
    fresh = main(args + ["--name", "fresh", "--hp", "fresh_flights_every=1"])
    assert json.loads((fresh / "summary.json").read_text())["flight_draws"] == 2
    # the first epoch is on the same flights, the second on seeds 1012+: the networks part after the first
    h = [json.loads((r / "summary.json").read_text())["selection_history"] for r in (same, fresh)]
    assert h[0][0]["train_rmse_m"] == h[1][0]["train_rmse_m"] and h[0][1]["train_rmse_m"] != h[1][1]["train_rmse_m"]
    assert (fresh / "policy.npz").read_bytes() != (same / "policy.npz").read_bytes()
    # the head in training is fitted on the last draw's looks, and --add-covariance finds the same draw
    nc = main(args + ["--name", "nocov", "--hp", "fresh_flights_every=1", "--hp", "covariance_epochs=0"])
    assert main(["--method", "window", "--add-covariance", str(nc), "--quiet"]) == nc
    for f in ("policy.npz", "best/policy.npz"):
        assert (nc / f).read_bytes() == (fresh / f).read_bytes(), f
    with pytest.raises(SystemExit, match=r"--seed: the training flights' seeds 899980..900003 must lie .* 2 draw"):
        main(args + ["--name", "c", "--seed", "899980", "--hp", "fresh_flights_every=1"])
    with pytest.raises(SystemExit, match=r"--hp fresh_flights_every: must be an integer in \[0, 10000\], got -1"):
        main(args + ["--name", "c", "--hp", "fresh_flights_every=-1"])


@pytest.mark.parametrize("covariance, q_looks", [(False, 0), (True, 0), (False, 4)])
def test_the_env_wrapper_gives_the_evaluations_numbers(tmp_path, covariance, q_looks):
    import gymnasium as gym
    from radar_env.envs.core import draw_setup_and_episode
    from agents.policies.checks import env_kwargs_from_json
    wc = load_learned(_save_cov(tmp_path)[0] if covariance else _save(tmp_path, q_looks=q_looks))
    assert wc.policy.q_looks == q_looks
    base = load_learned("policy_bp")
    cfg = base.env_config
    seeds = [31, 32]
    eps = [draw_setup_and_episode(cfg.scenario, cfg.radar, cfg.random_scenario_config, np.random.default_rng(s),
                                  cfg.warmup_scans) for s in seeds]
    run = wc.run(eps)
    if q_looks:
        # the q columns are not trivially equal: at the corrected looks the base's q is finite and changes from look
        # to look, and the correction with another q moves the estimates far more than the tolerance below
        from radar_env.sim.episode import stack_episodes
        brun = wc.policy.base_run(eps)
        corr = np.isfinite(run.extra["correction_m"])
        rows, looks = np.nonzero(corr)
        assert np.isfinite(brun.q_m_s2[corr]).all() and np.unique(brun.q_m_s2[corr]).size > 0.9 * corr.sum()
        assert (brun.q_m_s2[:, 1:] != brun.q_m_s2[:, :-1])[corr[:, 1:] & corr[:, :-1]].mean() > 0.9
        b = stack_episodes(eps)
        d = wc.policy.corrected_at(b, brun.x, brun.P, rows, looks, brun.q_m_s2)[0]
        d1 = wc.policy.corrected_at(b, brun.x, brun.P, rows, looks, np.full_like(brun.q_m_s2, 0.1))[0]
        assert np.max(np.abs(d - d1) / (np.abs(brun.x[rows, looks, :2]) + 1.0)) > 1e-6
    kw = env_kwargs_from_json(json.loads((BUNDLED_LEARNED["policy_bp"] / "env_config.json").read_text()))
    env = wcm.CorrectedEstimate(gym.make("RadarTrack-v0", **kw), wc.policy)
    with pytest.raises(ValueError, match="correction must be a WindowCorrection"):
        wcm.CorrectedEstimate(env, base.policy)
    worst, n = 0.0, 0
    for r, s in enumerate(seeds):
        obs, info = env.reset(seed=s)
        k = int(run.start_index[r]) - 1
        np.testing.assert_array_equal(info["corrected_estimate"], info["estimate"])   # the start look: uncorrected
        np.testing.assert_array_equal(info["corrected_covariance"], info["covariance"])
        state, start = None, True
        while True:
            action, state = base.policy.predict(obs, state, episode_start=start)
            obs, _, term, trunc, info = env.step(action)
            start, k, n = False, k + 1, n + 1
            est = run.x[r, k]
            worst = max(worst, float(np.max(np.abs(info["corrected_estimate"] - est) / (np.abs(est) + 1.0))))
            C = run.P[r, k]         # the head's covariance, else the env's (the base's)
            worst = max(worst, float(np.max(np.abs(info["corrected_covariance"] - C) / (np.abs(C).max() + 1e-9))))
            if term or trunc:
                break
    assert n > 100 and worst < 1e-9


# ---- the covariance head
def _save_cov(tmp_path, name="wcc", base="policy_bp", window=4, layers=(8, 6), seed=0):
    """A correction with a covariance head (random weights) and the same correction without it."""
    arch = {"input_size": wcm.feature_count(window), "layers": list(layers), "covariance": True}
    w = _weights(arch, np.random.default_rng(seed))
    cfg = {"base": base, "window_looks": window, "scale_m": 300.0, "scale_m_s": 30.0, "architecture": arch}
    env = json.loads((BUNDLED_LEARNED[base] / "env_config.json").read_text())
    wcm.save_window_correction(tmp_path / name, w, cfg, env)
    plain = {k: v for k, v in w.items() if not k.startswith("cov.")}
    wcm.save_window_correction(tmp_path / (name + "_plain"), plain,
                               {**cfg, "architecture": {**arch, "covariance": False}}, env)
    return tmp_path / name, tmp_path / (name + "_plain")


def test_head_covariance_by_hand():
    raw = np.array([[np.log(2.0), 0.5, np.log(3.0), 0.0, -1.0, np.log(0.5), 0.25, 0.0, 2.0, np.log(1.5)]])
    L = np.zeros((4, 4))
    L[0, 0], L[1, 1], L[2, 2], L[3, 3] = 2.0, 3.0, 0.5, 1.5
    L[1, 0], L[2, 1], L[3, 0], L[3, 2] = 0.5 * 2.0, -1.0 * 3.0, 0.25 * 2.0, 2.0 * 0.5   # multiples of the column's
    u = np.array([300.0, 300.0, 30.0, 30.0])
    S = (L @ L.T + wcm.COV_FLOOR * np.eye(4)) * np.outer(u, u)
    th = 0.7
    c, s = np.cos(th), np.sin(th)
    rot = np.zeros((4, 4))
    rot[:2, :2] = rot[2:, 2:] = [[c, -s], [s, c]]
    P = wcm.head_covariance(raw, np.array([[c, s]]), 300.0, 30.0)[0]
    np.testing.assert_allclose(P, rot @ S @ rot.T, rtol=1e-12)
    # along the velocity (east) the frame is the world's
    np.testing.assert_allclose(wcm.head_covariance(raw, np.array([[1.0, 0.0]]), 300.0, 30.0)[0], S, rtol=1e-12)
    # any outputs, however extreme: exactly symmetric, positive definite to numpy's Cholesky
    rng = np.random.default_rng(0)
    for scale in (1.0, 30.0, 1e6):
        raw = rng.normal(size=(5000, 10)) * scale
        th = rng.uniform(0, 2 * np.pi, 5000)
        P = wcm.head_covariance(raw, np.stack([np.cos(th), np.sin(th)], -1), 300.0, 30.0)
        assert np.array_equal(P, np.swapaxes(P, 1, 2)) and np.isfinite(P).all()
        np.linalg.cholesky(P)


def test_a_covariance_head_reports_its_covariance_and_keeps_the_estimate(tmp_path):
    from agents.evaluation.metrics import nees_values
    from agents.evaluation.suites import draw_suite
    from radar_env.sim.episode import stack_episodes
    eps = draw_suite("random_radars", 5, seed=900_000)
    d, plain = _save_cov(tmp_path)
    wc, wp = load_learned(d), load_learned(plain)
    assert wc.policy.has_covariance and not wp.policy.has_covariance
    r, rp = wc.run(eps), wp.run(eps)
    assert np.array_equal(r.x, rp.x, equal_nan=True)          # the head leaves the estimate as it is
    b = stack_episodes(eps)
    after = (np.arange(r.x.shape[1])[None] >= rp.start_index[:, None]) & np.isfinite(rp.x).all(-1)
    assert np.array_equal(r.P[~after], rp.P[~after], equal_nan=True)          # the base's where not corrected
    rows, looks = np.nonzero(after)
    base = load_learned("policy_bp").run(eps)                  # the inputs read the base's estimate
    F, frame = wcm.look_features(b.t_s, b.z_m, b.R_m2, b.detected, base.x, base.P, rows, looks, 4, 300.0)
    raw = wcm.network_forward(wc.policy.w, 2, F, covariance=True)[1]
    np.testing.assert_array_equal(r.P[rows, looks], wcm.head_covariance(raw, frame, 300.0, 30.0))
    assert np.isfinite(nees_values((r.x - b.truth)[after], r.P[after])).all()     # every one a covariance
    # a row alone equals the row in its batch, covariance included
    alone = wc.run([eps[3]])
    n = alone.P.shape[1]
    assert np.array_equal(alone.P[0], r.P[3, :n], equal_nan=True)


def test_the_trainers_torch_covariance_is_the_compiled_one():
    """The head's covariance is written twice (torch for the fit's gradients, numba for the tracker): along east
    with unit scales the two are the same matrix, clips and floor included."""
    import torch
    from agents.training.window import _torch_cov
    rng = np.random.default_rng(2)
    raw = np.concatenate([rng.normal(size=(200, 10)), rng.normal(size=(50, 10)) * 40.0])     # inside and past clips
    want = wcm.head_covariance(raw, np.tile([1.0, 0.0], (len(raw), 1)), 1.0, 1.0)
    got = _torch_cov(torch, torch.from_numpy(raw)).numpy()
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())


def test_covariance_fields_are_checked_in_one_line(tmp_path):
    d, _ = _save_cov(tmp_path)
    meta = json.loads((d / "policy.json").read_text())
    arch = meta["architecture"]
    for change, msg in (({"architecture": {**arch, "covariance": "yes"}}, r"'architecture.covariance' must be true"),
                        ({"scale_m_s": 0.0}, r"field 'scale_m_s' must be > 0 \(m/s\) with a covariance head"),
                        ({"scale_m_s": None}, r"field 'scale_m_s' must be a finite number")):
        (d / "policy.json").write_text(json.dumps({**meta, **change}))
        with pytest.raises(ValueError, match=msg) as e:
            load_learned(d)
        assert "\n" not in str(e.value)
    (d / "policy.json").write_text(json.dumps(meta))
    w = dict(np.load(d / "policy.npz"))
    del w["cov.bias"]
    np.savez(d / "policy.npz", **w)
    with pytest.raises(ValueError, match=r"cov.bias"):
        load_learned(d)


def test_the_covariance_fit_recovers_a_constant_covariance():
    """With errors of one covariance whatever the inputs, the likelihood's maximum is their sample covariance
    (closed form): the head's covariance there, to the sampling and optimisation error."""
    import torch
    from agents.training.window import _torch_cov, fit_covariance_head
    rng = np.random.default_rng(5)
    n = 20_000
    F = rng.normal(size=(n, 5))
    w = {"layer.0.weight": rng.normal(size=(6, 5)) * 0.5, "layer.0.bias": np.zeros(6)}
    A = np.array([[1.0, 0, 0, 0], [0.3, 0.5, 0, 0], [0.8, -0.2, 2.0, 0], [0.1, 0.4, -0.5, 0.7]])
    E = rng.normal(size=(n, 4)) @ A.T
    head, stats = fit_covariance_head(w, [6], F, E, epochs=200, seed=0)   # 1,000 steps
    h = np.tanh(F @ w["layer.0.weight"].T + w["layer.0.bias"])
    S = _torch_cov(torch, torch.from_numpy(h @ head["cov.weight"].T + head["cov.bias"])).numpy()
    sample = E.T @ E / n
    assert np.abs(S.mean(0) - sample).max() < 0.01 * np.abs(sample).max()
    assert abs(stats["anees_training"] - 1.0) < 0.01
