"""The samplers of fitting.sample (emcee, NUTS, HMC): exact posteriors, diagnostics equal to
ArviZ's, bit-identical resume, ArviZ export, undetermined directions, the status.

The known answer is a linear-Gaussian model written in the library's own residual form (a
fitting.AbstractModel whose prediction is linear in θ, through fitting.Problem): with the
prior box far wider than the posterior, the posterior of θ is exactly Gaussian with mean the
least-squares solution and covariance (JᵀJ)⁻¹ — what fitting.fit's Laplace approximation
gives, without approximation. Each sampler's mean and covariance must agree within 4
Monte-Carlo standard errors (from the run's own bulk ESS). With a duplicated basis function
the model has a null direction θ2 − θ3; the samplers hold it at the fit's value and sample the determined subspace,
where the posterior is again exactly Gaussian (mean θ̂, covariance (JᵀJ)⁺), and the status must
be decided by the determined quantities only.
"""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from brdfscale import fitting, InvalidInputError
from brdfscale.choices import SAMPLE
from brdfscale.fitting import _diagnostics
from tests.helpers import Linear, linear_measurements, parametric_dataset, TRUTHS


@pytest.fixture(scope="module")
def linear():
    """The linear-Gaussian problem, its fit, and the exact posterior (mean, covariance)."""
    data = fitting.Dataset.from_measurements(linear_measurements())
    model = Linear()
    problem = fitting.Problem(model, data)
    res = fitting.fit(model, data, starts=1)
    J = np.asarray(jax.jacfwd(problem.residuals)(jnp.zeros(3)))
    r0 = np.asarray(problem.residuals(jnp.zeros(3)))
    mean = np.linalg.lstsq(J, -r0, rcond=None)[0]
    cov = np.linalg.inv(J.T @ J)
    assert res.determined and np.allclose(res.theta, mean, atol=1e-6) and np.allclose(res.covariance, cov, rtol=1e-6)
    return problem, res, mean, cov


SAMPLERS = {
    "emcee": dict(sampler="emcee", walkers=8, steps=1000),
    "nuts": dict(sampler=fitting.NUTS(warmup=150), steps=800),
    "hmc": dict(sampler=fitting.HMC(warmup=150), steps=800),
    "imh": dict(sampler="imh", steps=800),
}
CHUNK = 100  # one compiled block for every NUTS/HMC test (the compiled program is reused across tests)


def _assert_gaussian(draws, result, mean, cov, names):
    """Mean within 4 MCSE, variances and correlations within 4 of their Monte-Carlo standard errors."""
    summary = result.summary()
    ess = min(summary[n]["ess_bulk"] for n in names)
    for i, name in enumerate(names):
        assert abs(summary[name]["mean"] - mean[i]) < 4 * summary[name]["mcse_mean"], name
    est = np.cov(draws, rowvar=False)
    sd, sd_est = np.sqrt(np.diag(cov)), np.sqrt(np.diag(est))
    np.testing.assert_allclose(sd_est, sd, rtol=4 * math.sqrt(0.5 / ess))
    rho, rho_est = cov / np.outer(sd, sd), est / np.outer(sd_est, sd_est)
    assert np.all(np.abs(rho_est - rho) <= 4 * (1 - rho**2) / math.sqrt(ess) + 1e-12)


@pytest.mark.parametrize("name", list(SAMPLERS))
def test_each_sampler_recovers_the_exact_linear_gaussian_posterior(linear, name):
    problem, res, mean, cov = linear
    s = fitting.sample(problem, res, chunk=CHUNK, progress=False, seed=3, **SAMPLERS[name])
    assert s.sampler == name and s.chains == 4
    _assert_gaussian(s.samples, s, mean, cov, problem.model.names)
    assert s.samples.shape == (s.draws.shape[0] * s.draws.shape[1], 3) and s.draws.shape[0] == s.chain.shape[1]
    d = s.diagnostics()
    assert d["criteria"]["checked"] == ["q0", "q1", "q2"] and set(d["summary"]) == {"t0", "t1", "t2", "q0", "q1", "q2"}
    if name == "emcee":
        # each independent ensemble is one of ArviZ's chains, its draws its 8 walkers' trajectories
        # one after another (R̂ across ensembles, not walkers, as issue 30 asks); on 4 ensembles × 8
        # walkers × ~930 kept steps (≈ 28 τ per walker) R̂ and bulk ESS pass, and the status says so
        assert s.chain.shape == (1000, 4 * 8, 3) and s.warmup["steps"] == s.burn
        by_chain = s.by_chain(s.quantities["q0"][s.burn :])
        assert by_chain.shape == (4, 8 * (1000 - s.burn))
        assert s.summary()["q0"] == _diagnostics.summary_row(by_chain)
        assert s.status == "converged", s.status
    elif name == "imh":
        # no warm-up; the Student-t proposal (10 degrees of freedom) about the exact posterior is accepted at the
        # rate E[min(1, w'/w)] of its importance weights, computed here by Monte Carlo from the t and the Gaussian
        assert s.status == "converged", s.status
        assert s.chain.shape == (800, 4, 3) and s.burn == 0 and s.warmup["steps"] == 0
        rng = np.random.default_rng(0)
        xi = rng.standard_normal((200_000, 3)) / np.sqrt(rng.chisquare(10, (200_000, 1)) / 10)
        r2 = np.sum(xi**2, axis=1)
        log_w = -0.5 * r2 + 6.5 * np.log1p(r2 / 10)  # log N(ξ) − log t₁₀(ξ), up to a constant
        w = np.exp(log_w - log_w.max())
        # E over independent pairs (current state ~ the posterior, i.e. q weighted by w; proposal ~ q)
        state = rng.choice(w.size, 20_000, p=w / w.sum())
        proposal = rng.integers(0, w.size, 20_000)
        expected = np.mean(np.minimum(1.0, w[proposal] / w[state]))
        assert abs(s.acceptance - expected) < 0.02, (s.acceptance, expected)
        assert s.warmup["acceptance_rate"] == pytest.approx(s.acceptance, rel=1e-12)
    else:
        assert s.status == "converged", s.status
        assert s.chain.shape == (950, 4, 3) and s.burn == 150 and s.divergent == 0
        assert s.warmup["steps"] == 150 and len(s.warmup["step_size"]) == 4
        eps = np.asarray(s.warmup["step_size"])
        after = s.stats["step_size"][150:]
        if name == "nuts":
            # fixed after the warm-up: the same ε every step, the record's (np.exp of the state's
            # log ε on the host; XLA's exp inside the kernel may differ from it in the last bit)
            assert np.all(after == after[0])
            np.testing.assert_allclose(after[0], eps, rtol=1e-14)
        else:
            assert np.all((after >= 0.8 * eps * (1 - 1e-12)) & (after <= 1.2 * eps * (1 + 1e-12)))  # jittered ±20 %
        assert np.any(s.stats["step_size"][:150] != eps)  # adapted during it
        assert 0.6 < s.acceptance < 0.95


@pytest.mark.slow  # ≈ 10–15 s: the eager chunk dispatches op by op (the default suite's 6-minute budget)
def test_one_imh_chunk_under_jit_equals_eager_and_its_acceptance_is_scipys_t_density(linear):
    """IMH's compiled chunk (``_advance``, one program for all chains) equals the same steps run eagerly
    (``jax.disable_jit``); and the acceptance probability of every chain's first step, recomputed from the same
    random numbers with SciPy's multivariate t density as q — min(1, w′/w), w = p/q — equals the kernel's (whose
    log q drops the constants that cancel)."""
    from scipy import stats

    from brdfscale.fitting import _posterior, _sample_imh

    problem, res, _, _ = linear
    post = _posterior.target(problem, res)
    mode, cov = _posterior.laplace(post, res)
    root = 1.3 * _posterior.covariance_root(cov)  # a proposal wider than the posterior: not every step accepted
    dof, chains, n = 5.0, 4, 3
    z0 = _posterior.initial_positions(mode, _posterior.covariance_root(cov), chains, np.random.default_rng(1))
    carry = _sample_imh._host(
        _sample_imh._initial_carry(post, jnp.asarray(z0), jnp.asarray(mode), jnp.asarray(root), dof)
    )
    key = jax.random.PRNGKey(7)
    jitted = _sample_imh._advance(post, dof, carry, np.int64(0), np.int64(n), key, n)
    with jax.disable_jit():
        eager = _sample_imh._advance(post, dof, carry, np.int64(0), np.int64(n), key, n)
    for a, b in zip(jax.tree_util.tree_leaves(jitted), jax.tree_util.tree_leaves(eager)):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12)
    acceptance = np.asarray(jitted[1][2]["acceptance_rate"])
    assert 0 < np.mean(acceptance) < 1
    q = stats.multivariate_t(loc=mode, shape=root @ root.T, df=dof)
    log_p = eqx.filter_jit(lambda target, z: target.log_density(z))
    keys = jax.random.split(jax.random.fold_in(key, 0), chains)
    for c in range(chains):
        k_xi, k_g, _ = jax.random.split(keys[c], 3)
        xi = jax.random.normal(k_xi, (mode.size,), jnp.float64)
        xi = xi / jnp.sqrt(2.0 * jax.random.gamma(k_g, dof / 2, (), jnp.float64) / dof)
        proposal = mode + root @ np.asarray(xi)
        w_new = float(log_p(post, jnp.asarray(proposal))) - q.logpdf(proposal)
        w_old = float(log_p(post, jnp.asarray(z0[c]))) - q.logpdf(z0[c])
        assert acceptance[0, c] == pytest.approx(min(1.0, math.exp(w_new - w_old)), rel=1e-9)


# -- auto: IMH where its proposal covers the posterior, NUTS elsewhere ----------------------


@pytest.mark.parametrize(
    "draws",
    [
        lambda rng: rng.standard_normal(2000),  # log-normal weights: k̂ ≈ 0.4
        lambda rng: np.log(rng.pareto(1 / 0.8, 3000)),  # Pareto weights of shape k = 0.8
        lambda rng: -np.log(rng.uniform(size=1000)),  # exponential weights: k = 0
        lambda rng: np.log(rng.uniform(size=500)),  # bounded weights: k < 0
    ],
)
def test_pareto_k_is_arviz_psis_k_hat(draws):
    """fitting.pareto_k against ArviZ's Pareto smoothed importance sampling (az.psislw) on weights of known tails."""
    az = pytest.importorskip("arviz")
    log_w = draws(np.random.default_rng(4))
    expected = float(az.psislw(log_w.copy())[1])
    assert fitting.pareto_k(log_w) == pytest.approx(expected, rel=1e-12, abs=1e-12)
    assert fitting.pareto_k(log_w + 123.0) == pytest.approx(expected, rel=1e-12, abs=1e-12)  # any offset


def test_pareto_k_of_heavy_tails_is_large_and_of_too_few_weights_infinite():
    rng = np.random.default_rng(5)
    assert fitting.pareto_k(np.log(rng.pareto(1 / 1.5, 4000))) > 1.0  # shape 1.5: no mean
    assert fitting.pareto_k(rng.standard_normal(4)) == math.inf  # fewer than 5 weights
    assert fitting.pareto_k(np.full(100, -np.inf)) == math.inf  # every weight 0
    spiky = np.concatenate([np.zeros(1000), [50.0]])  # one weight dominates: the tail above the cut holds 1
    assert fitting.pareto_k(spiky) == math.inf


def test_auto_chooses_imh_on_a_gaussian_posterior_and_recovers_it(linear):
    """The linear-Gaussian posterior is what the Laplace approximation says it is: the Student-t proposal's weights
    are bounded (k̂ well below 0.7), so auto runs IMH — recorded in ``chosen_by`` — and its draws are the exact
    posterior's."""
    problem, res, mean, cov = linear
    s = fitting.sample(problem, res, chunk=CHUNK, progress=False, seed=3, steps=800)  # the default: auto
    assert s.sampler == "imh" and s.status == "converged", s.status
    chosen = s.chosen_by
    assert chosen is not None and chosen["name"] == "auto" and chosen["chose"] == "imh"
    assert chosen["pareto_k"] < 0.5 and chosen["limit"] == pytest.approx(min(0.7, 1 - 1 / math.log10(2000)))
    assert chosen["draws"] == SAMPLE.auto_draws and s.diagnostics()["chosen_by"] == chosen
    assert s.timing is not None and s.timing["choice_s"] > 0
    # k̂ is that of the proposal's weights, recomputed here from the same draws
    from brdfscale.fitting import _posterior

    weights = fitting.IMH().log_weights(_posterior.target(problem, res), res, draws=2000, seed=3, batch=4)
    assert chosen["pareto_k"] == fitting.pareto_k(weights)
    _assert_gaussian(s.samples, s, mean, cov, s.names)


def test_auto_falls_back_where_k_hat_is_above_its_limit(linear):
    """With a limit no k̂ meets, auto runs its fallback (here NUTS with a short warm-up); the record says why."""
    problem, res, mean, cov = linear
    rule = fitting.Auto(fallback=fitting.NUTS(warmup=150), max_k=-10.0)
    s = fitting.sample(problem, res, sampler=rule, chunk=CHUNK, progress=False, seed=3, steps=800)
    assert s.sampler == "nuts" and s.chosen_by["chose"] == "nuts" and s.chosen_by["limit"] == -10.0
    assert s.chosen_by["pareto_k"] > -10.0 and s.warmup["steps"] == 150
    _assert_gaussian(s.samples, s, mean, cov, s.names)


@pytest.mark.wrong_types
def test_auto_refuses_samplers_of_the_wrong_kind():
    with pytest.raises(InvalidInputError, match="imh must be a fitting.IMH"):
        fitting.Auto(imh=fitting.NUTS())  # type: ignore[arg-type]
    with pytest.raises(InvalidInputError, match="fallback must be a sampler object"):
        fitting.Auto(fallback=fitting.Auto())  # type: ignore[arg-type]


def test_an_interrupted_auto_run_resumes_with_the_sampler_its_checkpoint_records(linear, tmp_path, monkeypatch):
    """The choice is part of the checkpoint's signature: a resumed run continues with the sampler that wrote the
    chain — even where k̂, recomputed, would now choose the other (here made to) — bit for bit."""
    problem, res, _, _ = linear
    kw = dict(chunk=CHUNK, progress=False, seed=5, steps=250)
    full = fitting.sample(problem, res, **kw)
    assert full.sampler == "imh"
    with monkeypatch.context() as patch:
        _interrupt_after(patch, fitting._sample_imh, "_advance", 2)
        with pytest.raises(KeyboardInterrupt):
            fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)
    with monkeypatch.context() as patch:
        patch.setattr(fitting._sample_auto, "pareto_k", lambda weights: 5.0)  # a fresh choice would be NUTS
        assert fitting.sample(problem, res, **kw).sampler == "nuts"
        resumed = fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)
    assert resumed.sampler == "imh" and resumed.chosen_by == full.chosen_by
    assert np.array_equal(resumed.chain, full.chain) and np.array_equal(resumed.log_prob, full.log_prob)


# -- resume -------------------------------------------------------------------------------

RESUMABLE = {
    "emcee": dict(sampler=fitting.Emcee(walkers=8), steps=60),
    "nuts": dict(sampler=fitting.NUTS(warmup=150), steps=150),
    "hmc": dict(sampler=fitting.HMC(warmup=150), steps=150),
    "nuts-windows": dict(sampler=fitting.NUTS(warmup=40, adapt_mass_matrix=True), steps=150),
    "imh": dict(sampler=fitting.IMH(dof=5.0), steps=250),
}


def _interrupt_after(monkeypatch, module, name, calls):
    """Make ``module.name`` raise KeyboardInterrupt on its ``calls + 1``-th call."""
    original, count = getattr(module, name), {"n": 0}

    def interrupting(*args, **kwargs):
        count["n"] += 1
        if count["n"] > calls:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, interrupting)


@pytest.mark.parametrize("name", list(RESUMABLE))  # nuts-windows: the default suite's one run of window adaptation
def test_an_interrupted_run_resumes_bit_identically(linear, name, tmp_path, monkeypatch):
    """Killed in the middle of the run (after some chunks were committed), the run resumes
    from the checkpoint and gives the uninterrupted run's chain, log-probabilities and
    statistics bit for bit; so does a file whose commit marker lags behind its newest state
    slot (a kill between the state's write and the commit)."""
    import h5py

    problem, res, _, _ = linear
    kw = dict(chunk=50 if name == "emcee" else CHUNK, progress=False, seed=5, **RESUMABLE[name])
    full = fitting.sample(problem, res, **kw)
    with monkeypatch.context() as patch:
        if name == "emcee":  # 1 call for the start, 2 per step: stops inside the second chunk
            _interrupt_after(patch, fitting._sample_emcee, "_batched_log_density", 1 + 2 * 55)
        elif name == "imh":  # two chunks are done
            _interrupt_after(patch, fitting._sample_imh, "_advance", 2)
        else:  # the warm-up (its block, for the windows) and one chunk are done
            _interrupt_after(patch, fitting._sample_blackjax, "_advance", 1 if name == "nuts-windows" else 2)
        with pytest.raises(KeyboardInterrupt):
            fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)
    with h5py.File(tmp_path / "c.h5") as f:
        committed = int(f.attrs["steps_done"])
    # NUTS/HMC chunks end where the warm-up (150 steps) does: 100 + 50 committed after two chunks
    assert committed == {"emcee": 50, "nuts": 150, "hmc": 150, "nuts-windows": 140, "imh": 200}[name]
    resumed = fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)
    for a, b in [(full.chain, resumed.chain), (full.log_prob, resumed.log_prob)] + [
        (full.stats[k], resumed.stats[k]) for k in full.stats
    ]:
        assert a.dtype == b.dtype and np.array_equal(a, b)
    assert resumed.summary() == full.summary() and resumed.warmup.keys() == full.warmup.keys()
    with h5py.File(tmp_path / "c.h5", "r+") as f:
        steps = sorted(int(e) for e in f["chunks/end"][()])[-2:]  # the last two chunks' ends
        f.attrs["steps_done"] = steps[0]  # the chunk before the last: as if the last commit never happened
    again = fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)
    assert np.array_equal(again.chain, full.chain) and np.array_equal(again.log_prob, full.log_prob)
    with h5py.File(tmp_path / "c.h5", "r+") as f:
        f.attrs["steps_done"] = steps[0] - 1  # no chunk ends at this step: reported as damaged, not guessed
    with pytest.raises(fitting_errors().MeasurementFileError, match="damaged"):
        fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)


@pytest.mark.parametrize("name", ["emcee", "imh", "nuts"])
def test_a_time_limit_ends_the_run_after_a_chunk_of_draws_and_the_checkpoint_continues_it(linear, name, tmp_path):
    """time_limit: the run ends at a chunk's end once the limit has passed, with its warm-up complete and at least
    two draws in, its chunks of draws paced to the time left (here a limit already passed: the warm-up and exactly
    two draws); the result and its status say so; the same call with the checkpoint and no limit continues the run
    to the uninterrupted run's chain, bit for bit."""
    problem, res, _, _ = linear
    kw = dict(chunk=50 if name == "emcee" else CHUNK, progress=False, seed=5, **RESUMABLE[name])
    full = fitting.sample(problem, res, **kw)
    assert full.stopped is None and full.diagnostics()["stopped"] is None
    cut = fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", time_limit=1e-9, **kw)
    # emcee and IMH: two steps; NUTS: the warm-up (150) and two draws
    held, asked = {"emcee": (2, 60), "imh": (2, 250), "nuts": (152, 300)}[name]
    assert cut.stopped == {"time_limit_s": 1e-9, "steps": held, "steps_asked": asked}
    assert cut.chain.shape[0] == held and np.array_equal(cut.chain, full.chain[:held])
    assert cut.status.startswith(f"not converged: time limit of 1e-09 s reached after {held} of {asked} steps")
    assert cut.diagnostics()["stopped"] == cut.stopped
    rest = fitting.sample(problem, res, checkpoint=tmp_path / "c.h5", **kw)
    assert rest.stopped is None and np.array_equal(rest.chain, full.chain)
    assert np.array_equal(rest.log_prob, full.log_prob)
    for bad in (0, -1.0, float("nan")):
        with pytest.raises(InvalidInputError, match="time_limit"):
            fitting.sample(problem, res, time_limit=bad, **kw)


def test_chunks_of_draws_are_paced_to_the_time_left(monkeypatch):
    """fitting._sampler.paced with the clock fixed: no deadline, the chunk; past it, only what brings the draws to
    two; no pace measured yet, PROBE steps; else the steps that fit the time left at the measured pace, within
    [max(1, 2 − drawn), n]."""
    from brdfscale.fitting import _sampler

    monkeypatch.setattr(_sampler.time, "monotonic", lambda: 100.0)
    assert _sampler.paced(200, None, 5.0, 10, 0) == 200
    assert _sampler.paced(200, 99.0, 5.0, 10, 0) == 2 and _sampler.paced(200, 99.0, 5.0, 10, 1) == 1
    assert _sampler.paced(200, 110.0, 0.0, 0, 0) == _sampler.PROBE
    assert _sampler.paced(200, 110.0, 5.0, 10, 0) == 20  # 10 s left at 0.5 s a step
    assert _sampler.paced(10, 110.0, 5.0, 10, 0) == 10 and _sampler.paced(200, 100.1, 5.0, 10, 0) == 2
    assert _sampler.paced(200, 100.1, 5.0, 10, 7) == 1
    assert not _sampler.out_of_time(None, 5) and not _sampler.out_of_time(99.0, 1) and _sampler.out_of_time(99.0, 2)


def fitting_errors():
    import brdfscale

    return brdfscale


# -- diagnostics --------------------------------------------------------------------------

STORED = (
    "tests/data/chains/linear_gaussian.npz"  # written by fitting.sample (NUTS 4 × 301 draws; emcee 16 walkers × 150)
)


def test_rhat_ess_and_mcse_equal_arviz_on_stored_chains():
    az = pytest.importorskip("arviz")
    stored = np.load(STORED)
    nuts, emcee_walkers = stored["nuts"], stored["emcee"]
    cases = {
        "nuts": nuts,
        "emcee (burn-in included)": emcee_walkers,
        "shifted chain": nuts + np.array([0.0, 0.0, 0.3, 0.0])[:, None, None] * nuts.std(axis=(0, 1)),
        "ties": np.round(nuts * 20) / 20,
        "one chain": nuts[:1],
        "even draws": nuts[:, :300],
    }
    for label, x in cases.items():
        reference = az.summary(az.convert_to_dataset(x), kind="all", round_to="none")
        for i in range(x.shape[-1]):
            ours = _diagnostics.summary_row(x[:, :, i])
            theirs = reference.loc[f"x[{i}]"]
            for key in _diagnostics.STATISTICS:
                if np.isnan(theirs[key]):
                    assert np.isnan(ours[key]), (label, i, key)
                else:
                    assert ours[key] == pytest.approx(theirs[key], rel=1e-10, abs=1e-14), (label, i, key)
    shifted = _diagnostics.summary_row(cases["shifted chain"][:, :, 0])
    assert shifted["r_hat"] > 1.01


def test_status_names_every_failed_criterion(linear):
    problem, res, _, _ = linear
    good = fitting.sample(problem, res, chunk=CHUNK, progress=False, seed=3, **SAMPLERS["nuts"])
    assert good.status == "converged" and good.problems() == []
    # too short: bulk ESS below 400, named per quantity
    short = dataclasses.replace(
        good,
        chain=good.chain[:190],
        log_prob=good.log_prob[:190],
        stats={k: v[:190] for k, v in good.stats.items()},
        quantities={k: v[:190] for k, v in good.quantities.items()},
    )
    assert short.status.startswith("not converged: ") and "ESS_bulk < 400 for q0 (" in short.status
    assert short.diagnostics()["problems"] == short.problems() and short.diagnostics()["status"] == short.status
    # one chain stuck away from the others: R̂ names the coordinate (θ when no quantities are given)
    chain = good.chain.copy()
    chain[:, 0, 1] += 10 * good.draws[:, :, 1].std()
    stuck = dataclasses.replace(good, chain=chain, quantities=None)
    assert stuck.status.startswith("not converged: R̂ > 1.01 for t1 (") and "t0" not in stuck.status
    # divergent transitions after the warm-up are named too
    stats = {**good.stats, "divergent": good.stats["divergent"].copy()}
    stats["divergent"][-3:, 0] = 1
    assert dataclasses.replace(good, stats=stats).status == "not converged: 3 divergent transitions after warm-up"
    assert "status=not converged" in repr(short)


def test_to_arviz_round_trips_through_netcdf(linear, tmp_path):
    az = pytest.importorskip("arviz")
    problem, res, _, _ = linear
    s = fitting.sample(problem, res, sampler=fitting.NUTS(warmup=150), steps=100, chunk=CHUNK, progress=False)
    data = s.to_arviz()
    assert isinstance(data, az.InferenceData)
    assert set(data.groups()) >= {"posterior", "sample_stats", "warmup_posterior", "warmup_sample_stats"}
    # one variable per coordinate and per determined quantity, named by the model (as ArviZ's converters)
    assert list(data.posterior.data_vars) == ["t0", "t1", "t2", "q0", "q1", "q2"]
    assert all(data.posterior[n].shape == (4, 100) for n in ("t0", "t1", "t2"))
    assert all(data.warmup_posterior[n].shape == (4, 150) for n in ("t0", "t1", "t2"))
    path = tmp_path / "run.nc"
    data.to_netcdf(str(path))
    back = az.from_netcdf(str(path))
    for group in ("posterior", "sample_stats", "warmup_posterior", "warmup_sample_stats"):
        assert getattr(back, group).equals(getattr(data, group)), group
    assert back.posterior.attrs["sampler"] == "nuts" and back.posterior.attrs["independent_chains"] == 4
    np.testing.assert_array_equal(np.stack([back.posterior[n].values for n in ("t0", "t1", "t2")], axis=-1), s.draws)
    np.testing.assert_array_equal(back.sample_stats["diverging"].values, s.stats["divergent"][150:].T.astype(bool))
    table = az.summary(back, kind="all", round_to="none")
    ours = s.summary()
    for name in ("t0", "t1", "t2"):
        for key in _diagnostics.STATISTICS:
            assert table.loc[name, key] == pytest.approx(ours[name][key], rel=1e-10)
    for name in ("q0", "q2"):
        assert table.loc[name, "r_hat"] == pytest.approx(ours[name]["r_hat"], rel=1e-10)


# nuts in the slow step (the default suite's 6-minute budget): hmc, its BlackJAX sibling, runs by default
@pytest.mark.parametrize("name", ["emcee", pytest.param("nuts", marks=pytest.mark.slow), "hmc"])
def test_arviz_summary_and_trace_by_variable_name_on_every_sampler(linear, name):
    """ArviZ's conventions on every sampler's output: one posterior variable per coordinate and
    per determined quantity, so ``az.summary(data, var_names=[…])`` selects by the model's names
    and gives the figures of SampleResult.summary(); one ArviZ chain per independent chain
    (emcee: per ensemble, its walkers' trajectories one after another — R̂ across ensembles),
    the walkers reported per ensemble as given."""
    az = pytest.importorskip("arviz")
    problem, res, _, _ = linear
    sampler = {"emcee": fitting.Emcee(walkers=8), "nuts": fitting.NUTS(warmup=50), "hmc": fitting.HMC(warmup=50)}[name]
    s = fitting.sample(problem, res, sampler=sampler, chains=3, steps=60, chunk=CHUNK, progress=False, seed=2)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)  # no "More chains than draws"
        data = s.to_arviz()
    walkers = 8 if name == "emcee" else 1
    assert (
        s.walkers == walkers
        and s.diagnostics()["walkers"] == walkers
        and data.posterior.attrs["walkers_per_chain"] == walkers
    )
    assert data.posterior.sizes["chain"] == 3 and data.posterior.sizes["draw"] == walkers * (
        60 + (50 if name != "emcee" else 0) - s.burn
    )
    table = az.summary(data, var_names=["t1", "q2"], kind="all", round_to="none")
    assert list(table.index) == ["t1", "q2"]
    ours = s.summary()
    for var in ("t1", "q2"):
        for key in _diagnostics.STATISTICS:
            assert table.loc[var, key] == pytest.approx(ours[var][key], rel=1e-10, nan_ok=True), (var, key)
    if name == "emcee":  # ensemble e's draws are walkers 8e … 8e + 7, each over the kept steps
        np.testing.assert_array_equal(
            data.posterior["t0"].values[1, : s.chain.shape[0] - s.burn], s.chain[s.burn :, 8, 0]
        )
    pytest.importorskip("matplotlib")
    axes = az.plot_trace(data, var_names=["q0"])
    assert np.asarray(axes).shape == (1, 2)
    import matplotlib.pyplot as plt

    plt.close("all")


def test_to_arviz_names_the_extra_when_arviz_is_missing(linear, monkeypatch):
    import builtins

    from brdfscale import MissingDependencyError

    problem, res, _, _ = linear
    s = fitting.sample(problem, res, sampler="emcee", walkers=8, steps=10, progress=False)
    real_import = builtins.__import__

    def no_arviz(name, *args, **kwargs):
        if name == "arviz" or name.startswith("arviz."):
            raise ImportError("No module named 'arviz'")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_arviz)
    with pytest.raises(MissingDependencyError, match=r"brdfscale\[mcmc\]"):
        s.to_arviz()
    assert s.summary()["t0"]["ess_bulk"] > 0  # the diagnostics need no ArviZ


# -- undetermined directions --------------------------------------------------------------


@pytest.fixture(scope="module")
def null_direction():
    data = fitting.Dataset.from_measurements(linear_measurements())
    model = Linear(duplicate=True)
    return fitting.Problem(model, data), fitting.fit(model, data, starts=1)


@pytest.mark.parametrize("sampler", [fitting.NUTS(warmup=200), fitting.HMC(warmup=200), fitting.Emcee(walkers=8)])
def test_an_undetermined_direction_is_held_and_the_determined_subspace_sampled_exactly(null_direction, sampler):
    """θ2 and θ3 multiply the same basis function: the data fix θ2 + θ3 only, and the fit
    names θ2 − θ3 undetermined. The samplers hold it at the fit's value and sample the
    determined subspace; there the posterior is exactly Gaussian with mean θ̂ and covariance
    the fit's pseudo-inverse (JᵀJ)⁺ — the known answer, within Monte-Carlo error. The status
    is decided on the determined quantities only, and the result states what was held."""
    problem, res = null_direction
    assert len(res.undetermined) == 1 and res.std["q2"] is None and res.std["q3"] is None
    steps = 1500 if sampler.name == "emcee" else 800
    s = fitting.sample(problem, res, sampler=sampler, steps=steps, chunk=CHUNK, progress=False, seed=2)
    u = s.samples[:, 2] - s.samples[:, 3]
    assert np.max(np.abs(u - (res.theta[2] - res.theta[3]))) < 1e-12  # held (the plane is exact in the box's middle)
    # the determined coordinates: t0, t1 and s = t2 + t3, against the fit's exact (pseudo-inverse) covariance
    A = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 1]], float)
    reduced = dataclasses.replace(s, names=("t0", "t1", "s"), chain=s.chain @ A.T, quantities=None)
    _assert_gaussian(reduced.samples, reduced, A @ res.theta, A @ res.covariance @ A.T, reduced.names)
    d = s.diagnostics()
    assert d["criteria"]["checked"] == ["q0", "q1"] and d["undetermined_quantities"] == ["q2", "q3"]
    (held,) = d["held_combinations"]
    assert held["combination"] == res.undetermined[0]["combination"]
    assert "held at the fit's values" in d["undetermined_note"] and "not sampled but held" in d["prior"]
    assert s.divergent == 0
    if sampler.name != "emcee":
        assert s.status == "converged", s.status


# -- arguments ----------------------------------------------------------------------------


def test_sampler_choices_and_arguments_are_checked(linear):
    problem, res, _, _ = linear
    assert fitting.SAMPLERS == {
        "emcee": fitting.Emcee,
        "nuts": fitting.NUTS,
        "hmc": fitting.HMC,
        "imh": fitting.IMH,
        "auto": fitting.Auto,
    }
    for kw, match in [
        (dict(sampler="metropolis"), "sampler must be one of"),
        (dict(sampler=3), "sampler must be one of"),
        (dict(sampler="nuts", walkers=8), "apply to emcee only"),
        (dict(sampler=fitting.Emcee(), moves="de"), "fitting.Emcee"),
        (dict(chains=0), "chains must be an integer ≥ 1"),
        (dict(sampler="hmc", steps=1), "steps"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            fitting.sample(problem, res, progress=False, **kw)
    for make, match in [
        (lambda: fitting.NUTS(warmup=-1), "warmup"),
        (lambda: fitting.NUTS(max_doublings=0), "max_doublings"),
        (lambda: fitting.NUTS(target_acceptance=1.0), r"target_acceptance must lie in \(0, 1\)"),
        (lambda: fitting.HMC(jitter=1.0), "jitter"),
        (lambda: fitting.HMC(trajectory_length=0), "trajectory_length"),
        (lambda: fitting.NUTS(warmup=10, adapt_mass_matrix=True), "warmup ≥ 20"),
        (lambda: fitting.Emcee(moves="gibbs"), "moves must be one of"),
        (lambda: fitting.IMH(dof=0.0), r"dof \(or math.inf: a Gaussian\) must be a finite number > 0"),
        (lambda: fitting.IMH(dof=-math.inf), r"dof \(or math.inf: a Gaussian\) must be"),
        (lambda: fitting.IMH(scale=0.0), "scale must be a finite number > 0"),
        (lambda: fitting.Auto(draws=50), "draws must be an integer ≥ 100"),
        (lambda: fitting.Auto(max_k=math.nan), "max_k must be a finite number"),
    ]:
        with pytest.raises(InvalidInputError, match=match):
            make()


@pytest.mark.wrong_types
def test_a_sampler_flag_that_is_not_a_bool_is_named():
    with pytest.raises(InvalidInputError, match="adapt_mass_matrix"):
        fitting.NUTS(adapt_mass_matrix="yes")


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["nuts", "hmc"])
def test_the_width_law_with_two_scales_converges_in_the_determined_subspace(sampler):
    """A real model with undetermined directions (the width law from two scales: mu_c and
    exponent undetermined, on a curved ridge the data leave flat): sampled in the determined
    subspace, NUTS and HMC converge without a divergence, and the determined amplitude and
    alpha_lobe get the fit's Laplace standard deviations (10 %)."""
    model = fitting.ParametricModel()
    _, data = parametric_dataset(model, TRUTHS[0], 0.01, seed=3, scales=(0.5, 4.0))
    res = fitting.fit(model, data, starts=2)
    assert len(res.undetermined) == 2
    s = fitting.sample(fitting.Problem(model, data), res, sampler=sampler, steps=1000, progress=False, seed=1)
    assert s.status == "converged" and s.divergent == 0, s.status
    summary = s.summary()
    for name in ("amplitude", "alpha_lobe"):
        assert summary[name]["sd"] == pytest.approx(res.std[name], rel=0.1)


def test_steps_none_is_the_samplers_own_and_the_gradient_default_converges_with_margin(linear):
    """``steps=None`` (the default) runs the sampler's ``default_steps`` — NUTS/HMC 1000 draws after
    100 warm-up steps, emcee 2000 (brdfscale.choices.SAMPLE) — and NUTS's defaults pass the
    convergence check (R̂ ≤ 1.01, ESS_bulk ≥ 400) on the linear-Gaussian posterior with ≥ 3× margin."""
    problem, res, mean, cov = linear
    assert fitting.Emcee().steps_of(None) == 2000 and fitting.Emcee().steps_of(7) == 7
    assert fitting.NUTS().steps_of(None) == fitting.HMC().steps_of(None) == 1000
    assert fitting.NUTS().warmup == fitting.HMC().warmup == SAMPLE.gradient_warmup == 100
    s = fitting.sample(problem, res, sampler="nuts", chunk=CHUNK, progress=False, seed=3)
    assert s.chain.shape == (100 + 1000, 4, 3) and s.burn == 100
    assert s.status == "converged"
    ess = min(row["ess_bulk"] for row in s.summary().values())
    assert ess >= 3 * _diagnostics.ESS_BULK_LIMIT, ess
    _assert_gaussian(s.samples, s, mean, cov, problem.model.names)
