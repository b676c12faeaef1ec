import numpy as np
import pytest

from probmap.geometry.se2 import wrap_angle
from probmap.models.measurement import RangeBearingModel
from probmap.models.motion import AckermannModel, VelocityModel


def num_jac(f, x, eps=1e-6):
    x = np.asarray(x, dtype=float)
    cols = []
    for i in range(x.size):
        dx = np.zeros_like(x)
        dx[i] = eps
        d = np.asarray(f(x + dx)) - np.asarray(f(x - dx))
        if d.size >= 2 and d.shape[-1] in (2, 3):
            d = d.copy()
        cols.append(d / (2 * eps))
    return np.stack(cols, -1)


@pytest.mark.parametrize("w", [0.7, -1.3, 1e-7, 0.0, 2e-4])
def test_velocity_jacobians_numerical(w):
    m = VelocityModel()
    x = np.array([1.0, -2.0, 0.4])
    u = np.array([1.5, w])
    dt = 0.5
    x_new, G, V = m.predict(x, u, dt)
    assert np.allclose(G, num_jac(lambda s: m.predict(s, u, dt)[0], x), atol=1e-6)
    assert np.allclose(V, num_jac(lambda s: m.predict(x, s, dt)[0], u), atol=1e-6)


def test_velocity_exact_arc_closed_form():
    m = VelocityModel()
    x = np.array([0.0, 0.0, 0.0])
    v, w, dt = 1.0, 0.5, 2 * np.pi  # half circle of radius 2 -> (0, 4, pi)
    x_new, _, _ = m.predict(x, [v, w], dt)
    assert np.allclose(x_new[:2], [0.0, 4.0], atol=1e-12)
    assert np.isclose(abs(x_new[2]), np.pi)
    # straight line limit
    x_new, _, _ = m.predict([1.0, 1.0, np.pi / 2], [2.0, 0.0], 1.5)
    assert np.allclose(x_new, [1.0, 4.0, np.pi / 2])


def test_velocity_noise_scaling():
    m = VelocityModel(reference_dt=0.1)
    assert np.allclose(m.control_covariance([1, 0], 0.05), 2 * m.control_covariance([1, 0], 0.1))
    with pytest.raises(ValueError):
        VelocityModel(alphas=(1, 2, 3))
    with pytest.raises(ValueError, match="dt"):
        m.predict([0, 0, 0], [1, 0], -1.0)


def test_both_motion_models_share_checks_and_noise_scaling():
    """predict's input check and control_covariance's reference_dt rule have one home: both
    models refuse the same bad inputs and scale their per-step noise the same way."""
    for make, u in ((VelocityModel, [1.2, 0.3]), (AckermannModel, [4.0, 0.1])):
        plain, ref = make(), make(reference_dt=0.1)
        M = plain.control_covariance(u, 0.05)
        assert np.allclose(ref.control_covariance(u, 0.05), 2.0 * M)  # 0.1 / 0.05
        assert np.allclose(ref.control_covariance(u, 0.0), M)  # dt = 0: unscaled
        with pytest.raises(ValueError, match="pose x must have shape"):
            plain.predict([0.0, 0.0], u, 0.1)
        with pytest.raises(ValueError, match="pose and control must be finite"):
            plain.predict([0.0, np.nan, 0.0], u, 0.1)
    a = AckermannModel(sigma_v=0.5, sigma_steer=0.05)
    assert np.allclose(a.control_covariance([9.0, -0.2], 0.3), np.diag([0.25, 0.0025]))


@pytest.mark.parametrize("ref", [(0.0, 0.0), (3.78, 0.5)])
def test_ackermann_jacobians_numerical(ref):
    m = AckermannModel(reference_point=ref)
    x = np.array([3.0, 1.0, -0.7])
    u = np.array([4.0, 0.2])
    _, G, V = m.predict(x, u, 0.025)
    assert np.allclose(G, num_jac(lambda s: m.predict(s, u, 0.025)[0], x), atol=1e-7)
    assert np.allclose(V, num_jac(lambda s: m.predict(x, s, 0.025)[0], u), atol=1e-7)


def test_ackermann_rates_kernel_closed_form_derivatives_and_singularity():
    """The shared speed-conversion kernel: closed forms, numerical derivatives, the singular case."""
    from probmap.models._motion_kernels import ackermann_rates

    L, H = 2.83, 0.76

    def rates(ve, al):
        ok, vc, k, *_ = ackermann_rates(ve, np.tan(al), H, L)
        assert ok
        return np.array([vc, k])

    ve, al = 3.0, 0.25
    ok, vc, k, dvc_dve, dvc_dal, dk_dve, dk_dal = ackermann_rates(ve, np.tan(al), H, L)
    assert ok
    assert np.isclose(vc, ve / (1 - np.tan(al) * H / L), rtol=1e-15)
    assert np.isclose(k, vc * np.tan(al) / L, rtol=1e-15)
    J = num_jac(lambda s: rates(s[0], s[1]), np.array([ve, al]))
    assert np.allclose([[dvc_dve, dvc_dal], [dk_dve, dk_dal]], J, rtol=1e-7, atol=1e-9)
    # tan(alpha) = L / H: v_e / 0, flagged (the model raises, the chain kernel returns a status)
    assert ackermann_rates(ve, L / H, H, L) == (False, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="singular"):
        AckermannModel(wheelbase=L, encoder_offset=H).predict(
            np.zeros(3), [ve, np.arctan(L / H)], 0.1
        )


def test_ackermann_circle_radius():
    # constant steering: the rear-axle centre drives a circle of radius L / tan(alpha)
    m = AckermannModel(encoder_offset=0.0)
    L, al, v = m.wheelbase, 0.1, 2.0
    x = np.zeros(3)
    n = 20000
    dt = (2 * np.pi * L / np.tan(al) / v) / n
    pts = [x[:2]]
    for _ in range(n):
        x, _, _ = m.predict(x, [v, al], dt)
        pts.append(x[:2])
    pts = np.array(pts)
    centre = np.array([0.0, L / np.tan(al)])
    r = np.linalg.norm(pts - centre, axis=1)
    assert np.allclose(r, L / np.tan(al), rtol=1e-3)
    # encoder offset: v_c = v_e / (1 - tan(a) H / L)
    mh = AckermannModel(encoder_offset=0.76)
    x1, _, _ = mh.predict(np.zeros(3), [2.0, 0.0], 1.0)
    assert np.isclose(x1[0], 2.0)
    x1, _, _ = mh.predict(np.zeros(3), [2.0, 0.1], 1e-4)
    assert np.isclose(x1[0] / 1e-4, 2.0 / (1 - np.tan(0.1) * 0.76 / 2.83), rtol=1e-6)


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (3.78, 0.5, -np.pi / 2)])
def test_range_bearing_jacobians_numerical(offset):
    m = RangeBearingModel(sensor_offset=offset)
    pose = np.array([1.0, 2.0, 0.3])
    lm = np.array([12.0, 9.0])
    z, H_x, H_m = m.predict(pose, lm)
    f = lambda p: m.predict(p, lm)[0]  # noqa: E731
    assert np.allclose(H_x, num_jac(f, pose), atol=1e-6)
    assert np.allclose(H_m, num_jac(lambda q: m.predict(pose, q)[0], lm), atol=1e-6)
    # inverse round trip and its Jacobians
    lm2, J_x, J_z = m.inverse(pose, z)
    assert np.allclose(lm2, lm)
    assert np.allclose(J_x, num_jac(lambda p: m.inverse(p, z)[0], pose), atol=1e-6)
    assert np.allclose(J_z, num_jac(lambda q: m.inverse(pose, q)[0], z), atol=1e-6)


def test_range_bearing_closed_form_and_many():
    m = RangeBearingModel()
    z, _, _ = m.predict([0.0, 0.0, np.pi / 2], [0.0, 3.0])
    assert np.allclose(z, [3.0, 0.0])
    z, _, _ = m.predict([0.0, 0.0, 0.0], [-1.0, -1e-12])
    assert -np.pi <= z[1] < np.pi
    rng = np.random.default_rng(3)
    lms = rng.uniform(-10, 10, (30, 2))
    pose = np.array([0.5, -0.5, 2.0])
    Z, HX, HM = m.predict_many(pose, lms)
    for i in range(30):
        z, hx, hm = m.predict(pose, lms[i])
        assert np.allclose(Z[i], z) and np.allclose(HX[i], hx) and np.allclose(HM[i], hm)
    assert np.all(np.abs(wrap_angle(Z[:, 1]) - Z[:, 1]) < 1e-12)


def test_range_bearing_bad_input():
    with pytest.raises(ValueError, match="R"):
        RangeBearingModel(R=np.eye(3))
    with pytest.raises(ValueError, match="positive"):
        RangeBearingModel(R=-np.eye(2))
    with pytest.raises(ValueError, match="zero range"):
        RangeBearingModel().predict([1.0, 1.0, 0.0], [1.0, 1.0])
