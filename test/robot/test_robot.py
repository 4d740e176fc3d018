"""The LWA-4P model: kinematics, M(q), psi, feedback linearization (paper eqs. 5-7),
regressor, base parameters and least-squares identification."""
import numpy as np
import pinocchio as pin
import pytest

from reachset_ros import robot as rb
from reachset_ros.errors import ReachsetError


@pytest.fixture(scope="module")
def model():
    return rb.load_model()


@pytest.fixture(scope="module")
def base(model):
    return rb.BaseParameters.from_model(model)


def _states(model, n, seed=0):
    return rb.random_states(model, n, np.random.default_rng(seed), qd_max=1.0, qdd_max=5.0)


def test_urdf_names_limits_and_kinematics_match_the_spec(model):
    assert model.joint_names == rb.JOINT_NAMES
    np.testing.assert_array_equal(model.effort_limit, [370, 370, 176, 176, 41.6, 20.1])
    np.testing.assert_array_equal(model.velocity_limit, np.full(6, 2.0))
    # position limits: the public URDF's hardware limits minus its 0.02 rad safety offset
    np.testing.assert_allclose(model.upper, np.array([6.28, 2.09, 6.28, 2.09, 6.28, 2.09]) - 0.02)
    np.testing.assert_allclose(model.lower, -model.upper)
    pm = model.pin_model
    # joint placements of SPEC.md "The paper's robot"
    spec = {1: ((0, 0, 0.11), (0, 0, 0)), 2: ((0, 0, 0), (np.pi / 2, 0, 0)),
            3: ((0, 0.350, 0), (0, np.pi, 0)), 4: ((0, 0, 0), (-np.pi / 2, np.pi, 0)),
            5: ((0, 0.005263, 0.305), (np.pi / 2, 0, np.pi)), 6: ((0, 0, 0), (-np.pi / 2, 0, 0))}
    for j, (xyz, rpy) in spec.items():
        M = pm.jointPlacements[j]
        np.testing.assert_allclose(M.translation, xyz, atol=1e-12)
        np.testing.assert_allclose(M.rotation, pin.rpy.rpyToMatrix(*rpy), atol=1e-12)
    # all axes z
    assert all(pm.joints[j].shortname() == "JointModelRZ" for j in range(1, 7))


def test_placeholder_inertias_are_physically_consistent(model):
    for i in range(1, 7):
        I = model.pin_model.inertias[i]
        assert I.mass > 0
        ev = np.linalg.eigvalsh(I.inertia)
        assert np.all(ev > 0)
        assert ev[0] + ev[1] >= ev[2] - 1e-12          # triangle inequality
    assert np.all(model.armature > 0)


def test_mass_matrix_symmetric_positive_definite(model):
    data = rb.create_data(model)
    Q, _, _ = _states(model, 20)
    for q in Q:
        M = rb.mass_matrix(model, data, q)
        np.testing.assert_allclose(M, M.T, atol=0)
        assert np.linalg.eigvalsh(M)[0] >= model.armature.min() - 1e-12


def test_feedback_linearization_and_its_inverse(model):
    data = rb.create_data(model)
    Q, QD, U = _states(model, 20, seed=1)
    for q, qd, u in zip(Q, QD, U):
        tau = rb.feedback_linearization(model, data, q, qd, u)
        M = rb.mass_matrix(model, data, q)
        np.testing.assert_allclose(tau, M @ u + rb.psi(model, data, q, qd), rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(rb.inverse_fl(model, data, q, qd, tau), u, atol=1e-9)
        # eq. (5) with this torque gives qdd = u_p (eq. 7)
        np.testing.assert_allclose(np.linalg.solve(M, tau - rb.psi(model, data, q, qd)), u,
                                   atol=1e-9)


def test_psi_parts(model):
    data = rb.create_data(model)
    q = np.array([0.3, -0.5, 0.7, 0.1, 0.9, -0.2])
    g = pin.computeGeneralizedGravity(model.pin_model, data, q)
    np.testing.assert_allclose(rb.psi(model, data, q, np.zeros(6)), g + model.friction.offset)
    qd = np.array([0.4, -0.3, 0.2, 0.5, -0.6, 0.7])
    f = rb.psi(model, data, q, qd) - pin.nonLinearEffects(model.pin_model, data, q, qd)
    np.testing.assert_allclose(f, model.friction.viscous * qd
                               + model.friction.coulomb * np.tanh(qd / rb.COULOMB_VELOCITY))


def test_regressor_reproduces_the_dynamics_and_base_parameters(model, base):
    data = rb.create_data(model)
    theta = rb.parameter_vector(model)
    assert len(theta) == len(rb.parameter_names(model)) == 84
    Q, QD, QDD = _states(model, 10, seed=2)
    for q, qd, a in zip(Q, QD, QDD):
        Y = rb.regressor(model, data, q, qd, a)
        np.testing.assert_allclose(Y @ theta, rb.feedback_linearization(model, data, q, qd, a),
                                   atol=1e-9)
        rnd = np.random.default_rng(3).standard_normal(84)
        np.testing.assert_allclose(Y @ rnd, Y[:, base.independent] @ base.base(rnd), atol=1e-8)
    assert 30 < base.rank < 84
    # standard parameters with given base parameters, closest to a prior
    beta = base.base(theta) * 1.1
    th = base.standard(beta, theta)
    np.testing.assert_allclose(base.base(th), beta, rtol=1e-9, atol=1e-12)
    assert rb.with_parameters(model, theta).pin_model.inertias[3].mass == pytest.approx(
        model.pin_model.inertias[3].mass)


def test_model_error_and_payload(model):
    assert rb.perturb(model, None) is model
    heavy = rb.perturb(model, rb.ModelError(mass_scale=1.2))
    for i in range(1, 7):
        assert heavy.pin_model.inertias[i].mass == pytest.approx(1.2 * model.pin_model.inertias[i].mass)
    # the original is untouched (models are values)
    assert model.pin_model.inertias[2].mass == pytest.approx(3.5)
    p = rb.add_payload(model, 2.0)
    assert p.pin_model.inertias[6].mass == pytest.approx(model.pin_model.inertias[6].mass + 2.0)
    r1 = rb.perturb(model, rb.ModelError.typical(seed=4))
    r2 = rb.perturb(model, rb.ModelError.typical(seed=4))
    np.testing.assert_array_equal(rb.parameter_vector(r1), rb.parameter_vector(r2))
    assert not np.allclose(rb.parameter_vector(r1), rb.parameter_vector(model))


def test_params_document_round_trip(model, tmp_path):
    import yaml
    other = rb.perturb(model, rb.ModelError.typical(seed=1)).replace(torque_scale=np.full(6, 0.5))
    doc = rb.model_params_dict(other)
    p = tmp_path / "m.yaml"
    p.write_text(yaml.safe_dump(doc))
    back = rb.load_model(params=p)
    np.testing.assert_allclose(rb.parameter_vector(back), rb.parameter_vector(other), atol=1e-12)
    np.testing.assert_allclose(back.torque_scale, 0.5)
    with pytest.raises(ReachsetError, match="do not match"):
        rb.apply_params(model, dict(doc, joints=["a"] * 6))
    with pytest.raises(ReachsetError, match="not found"):
        rb.load_model(params=tmp_path / "missing.yaml")
    with pytest.raises(ReachsetError, match="URDF not found"):
        rb.load_model(urdf=tmp_path / "missing.urdf")


def _synthetic(truth, n, seed, noise=0.0):
    data = rb.create_data(truth)
    Q, QD, QDD = _states(truth, n, seed)
    tau = np.array([rb.feedback_linearization(truth, data, q, qd, a)
                    for q, qd, a in zip(Q, QD, QDD)])
    logged = tau / truth.torque_scale
    logged = logged + noise * np.random.default_rng(seed).standard_normal(logged.shape)
    return Q, QD, QDD, logged


@pytest.mark.parametrize("method", ["ls", "lmi"])
def test_identification_recovers_a_perturbed_robot_with_unknown_torque_scale(model, base, method):
    truth = rb.perturb(model, rb.ModelError(mass_scale=1.3, inertia_scale=0.8, com_shift=0.01,
                                            armature_scale=1.5, viscous_scale=2.0,
                                            coulomb_scale=0.5, offset=0.3))
    truth = truth.replace(torque_scale=np.array([2.0, 3.0, 0.5, 1.5, 0.2, 0.1]))
    Q, QD, QDD, U = _synthetic(truth, 600, seed=5)
    gram = rb.torque_gram(model, rb.create_data(model), Q, QD, QDD, U)
    ident = rb.identify_inertial(model, gram, method=method, base=base, prior_weight=1e-9,
                                 scale_weight=1e-9)
    ph = rb.identify_inertial(model, gram, method="placeholder", base=base)
    rms_u = np.sqrt(np.mean(U ** 2, axis=0))
    assert np.all(ident.rms < 1e-3 * rms_u), ident.rms / rms_u
    assert np.all(ph.rms > 10 * ident.rms)
    # u_p = M^-1 (s tau_logged - psi) is what the pipeline needs: identical to the truth's.
    Qv, QDv, QDDv, Uv = _synthetic(truth, 50, seed=6)
    d1, d2 = rb.create_data(ident.model), rb.create_data(truth)
    for q, qd, u in zip(Qv, QDv, Uv):
        up = rb.inverse_fl(ident.model, d1, q, qd, rb.logged_to_torque(ident.model, u))
        up_true = rb.inverse_fl(truth, d2, q, qd, rb.logged_to_torque(truth, u))
        np.testing.assert_allclose(up, up_true, atol=2e-2 * max(1.0, np.abs(up_true).max()))
    # the scales are right up to one common factor
    ratio = ident.torque_scale / truth.torque_scale
    np.testing.assert_allclose(ratio / ratio[1], 1.0, rtol=2e-2)
    if method == "lmi":
        assert rb.min_mass_eigenvalue(ident.model, d1, Qv) > 0


def test_placeholder_fit_is_exact_when_the_prior_is_the_truth(model, base):
    truth = model.replace(torque_scale=np.array([2.0, 3.0, 0.5, 1.5, 0.2, 0.1]))
    Q, QD, QDD, U = _synthetic(truth, 300, seed=7)
    gram = rb.torque_gram(model, rb.create_data(model), Q, QD, QDD, U)
    ph = rb.identify_inertial(model, gram, method="placeholder", base=base)
    np.testing.assert_allclose(ph.torque_scale, truth.torque_scale, rtol=1e-7)
    gram_nm = rb.torque_gram(model, rb.create_data(model), Q, QD, QDD, U * truth.torque_scale)
    fixed = rb.identify_inertial(model, gram_nm, method="placeholder", base=base, fit_scale=False)
    np.testing.assert_allclose(fixed.torque_scale, 1.0)
    assert np.all(fixed.rms < 1e-6 * np.sqrt(np.mean((U * truth.torque_scale) ** 2, axis=0)))


def test_identify_rejects_bad_input(model):
    gram = rb.torque_gram(model, rb.create_data(model), *_states(model, 10), np.zeros((10, 6)))
    with pytest.raises(ReachsetError, match="too few"):
        rb.identify_inertial(model, gram)
    with pytest.raises(ReachsetError, match="unknown identification method"):
        rb.identify_inertial(model, gram, method="magic")
    with pytest.raises(ReachsetError, match="equal shapes"):
        rb.torque_gram(model, rb.create_data(model), np.zeros((3, 6)), np.zeros((3, 6)),
                       np.zeros((3, 6)), np.zeros((2, 6)))
