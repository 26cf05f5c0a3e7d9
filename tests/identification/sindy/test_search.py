"""Hyperparameter search (thesis 5.3.6): run-grouped folds, ranking by local-frame 5 s error
checked against an independent evaluation, recovery of the known model, the batched scoring of
all (alpha, T) against one model at a time, and the identify/evaluate commands end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from groundfloor.errors import InputError
from identification.sindy.evaluate import (
    errors_from_rollout,
    evaluate_model,
    make_windows,
    rollout,
)
from identification.sindy.figures import plot_grid
from identification.sindy.model import SindyModel, model_from_terms
from identification.sindy.regression import fit_sindy
from identification.sindy.search import (
    SearchGrid,
    StackedSindy,
    admissible,
    fold_assignment,
    search,
    select_one_se,
    select_parsimonious,
)
from tests.support.sindy_synth import SPARSE_TERMS, simulate_states

GRID = SearchGrid(s=(0.0,), tau=(1.0, 3.0), alpha=(0.05, 50.0), T=(0.2, 2.0), n_folds=2)


@pytest.fixture(scope="module")
def runs():
    """Four 40 s runs of the known sparse model."""
    return simulate_states(40.0, [61, 62, 63, 64])


@pytest.fixture(scope="module")
def result(runs):
    return search({0.0: runs}, GRID, names=["a", "b", "c", "d"], groups=[0, 0, 1, 2], n_top=3)


def test_folds_keep_each_run_on_one_side():
    fold = fold_assignment(np.array([0, 0, 1, 2, 2, 3]), n_folds=2)
    assert fold[0] == fold[1] and fold[3] == fold[4]  # segments of a run share its fold
    assert set(fold) == {0, 1}
    with pytest.raises(InputError, match="1 training run"):
        fold_assignment(np.array([0, 0]), 5)


def test_search_table_is_complete_and_ranked(result):
    tb = result.table
    assert len(tb["s"]) == GRID.size == 8
    assert np.all(np.diff(tb["pos_err_5s_m"]) >= 0)  # best first
    assert {tuple(f) for f in map(tuple, result.folds)} == {("a", "b", "d"), ("c",)}


def test_selected_model_recovers_the_known_terms(result):
    truth = model_from_terms(SPARSE_TERMS)
    np.testing.assert_array_equal(result.model.coef != 0, truth.coef != 0)
    assert result.model.hyperparameters["alpha"] == 0.05 and result.model.hyperparameters["T"] == 0.2
    assert result.table["pos_err_5s_m"][0] < 0.01 < result.table["pos_err_5s_m"][-1]


@pytest.mark.filterwarnings("ignore::identification.sindy.model.EnvelopeWarning")  # a held-out run is a bit wider
def test_cv_score_equals_an_independent_per_fold_evaluation(result, runs):
    """Re-derive one grid point's CV error with fit_sindy + evaluate_model, fold by fold."""
    names = ["a", "b", "c", "d"]
    fold = fold_assignment(np.array([0, 0, 1, 2]), 2)
    i = 3
    hp = {k: result.table[k][i] for k in ("tau", "alpha", "T")}
    sq, n = 0.0, 0
    for f in (0, 1):
        train = [r for r, g in zip(runs, fold) if g != f]
        held = [r for r, g in zip(runs, fold) if g == f]
        model = fit_sindy(train, "poly3", tau=hp["tau"], alpha=hp["alpha"], threshold=hp["T"])
        res = evaluate_model(model, held, dt=GRID.dt_eval)
        sq += res.n_windows * res.pos_err_5s_m**2
        n += res.n_windows
    assert np.sqrt(sq / n) == pytest.approx(result.table["pos_err_5s_m"][i], rel=1e-6)


def test_stacked_rollout_equals_one_model_at_a_time(runs):
    models = [fit_sindy(runs[:2], tau=2.0, alpha=a, threshold=t) for a, t in [(0.05, 0.2), (50.0, 2.0)]]
    stack = StackedSindy(models[0].library, np.stack([m.coef for m in models]))
    windows = make_windows(runs[2:], dt=0.05)
    both = rollout(stack, windows, batch_shape=(2,))
    for k, m in enumerate(models):
        np.testing.assert_allclose(both[k], rollout(m, windows), rtol=1e-10, atol=1e-12)
    eps_p, _ = errors_from_rollout(both, windows)
    assert eps_p.shape == (2, windows.n_windows, len(windows.t_rel))


def test_grid_plot_shows_the_table_values(result, tmp_path):
    fig = plot_grid(result, 0.0, tau=1.0, path=tmp_path / "grid.png")
    img = fig.axes[4].images[0].get_array()  # panel "pos. error 5 s"
    tb = result.table
    sel = (tb["tau"] == 1.0) & (tb["alpha"] == 50.0) & (tb["T"] == 2.0)
    assert img[1, 1] == pytest.approx(tb["pos_err_5s_m"][sel][0])
    assert (tmp_path / "grid.png").stat().st_size > 10_000


@pytest.mark.slow
def test_identify_and_evaluate_commands_end_to_end(small_trajectory, tmp_path, capsys):
    from sindy_ekf.cli import main

    model_path, id_json, ev_json = tmp_path / "m.json", tmp_path / "id.json", tmp_path / "ev.json"
    assert main(["identify", str(small_trajectory), "--out", str(model_path), "--quick", "--quiet",
                 "--json", str(id_json)]) == 0
    printed = capsys.readouterr().out
    model = SindyModel.load(model_path)
    summary = json.loads(id_json.read_text())
    assert summary["complexity"] == model.complexity > 0
    assert model.checks["passed"] and summary["checks_passed"]  # identify never selects a failing model
    # the summary puts the lag baseline beside the candidates and says whether the model beats it
    assert "lag baseline" in printed
    assert ("does NOT beat the lag" in printed) == (not summary["beats_lag"])
    assert main(["evaluate", str(small_trajectory), "--model", str(model_path), "--quiet",
                 "--json", str(ev_json)]) == 0
    printed = capsys.readouterr().out
    ev = json.loads(ev_json.read_text())
    assert ev["n_windows"] > 0 and 0 < ev["pos_err_5s_m"] < ev["baselines"]["constant_velocity"]["pos_err_5s_m"]
    assert set(ev["baselines"]) == {"constant_velocity", "unicycle", "lag"}
    assert ev["cv"]["pos_err_5s_m"] == pytest.approx(summary["cv_pos_err_5s_m"])  # the CV estimate beside the test
    assert "cross-validation estimate" in printed and "start-state smoothing sensitivity" in printed
    assert main(["evaluate", str(small_trajectory), "--model", str(tmp_path / "none.json"), "--quiet"]) == 2


@pytest.mark.slow
def test_identify_names_a_campaign_without_train_runs(small_trajectory, tmp_path, capsys):
    import shutil

    import yaml

    from sindy_ekf.cli import main

    camp = tmp_path / "all_test"
    shutil.copytree(small_trajectory, camp)
    meta = yaml.safe_load((camp / "campaign.yaml").read_text())
    for run in meta["runs"]:
        run["split"] = "test"
    (camp / "campaign.yaml").write_text(yaml.safe_dump(meta))
    assert main(["identify", str(camp), "--out", str(tmp_path / "m.json"), "--quick", "--quiet"]) == 2
    assert "all_test: campaign.yaml marks no run as train" in capsys.readouterr().err
    assert not (tmp_path / "m.json").exists()


def _table(err, se, complexity, stable=None, diverged=None):
    n = len(err)
    return {"pos_err_5s_m": np.asarray(err, float), "pos_err_5s_se_m": np.asarray(se, float),
            "complexity": np.asarray(complexity, float),
            "stable_at_rest": np.ones(n, bool) if stable is None else np.asarray(stable, bool),
            "diverged_frac": np.zeros(n) if diverged is None else np.asarray(diverged, float)}


def test_one_se_rule_against_a_hand_computation():
    """The one-SE rule from per-fold errors written out by hand (mean +- std/sqrt(K) of the fold RMS)."""
    folds = np.array([[1.0, 1.2, 0.9, 1.1],  # model A: 30 terms
                      [1.0, 1.15, 0.9, 1.1],  # model B: 10 terms, within one SE of D
                      [1.4, 1.6, 1.3, 1.5],  # model C: 3 terms, beyond
                      [0.95, 1.15, 0.85, 1.05]])  # model D: 50 terms, best
    complexity = [30, 10, 3, 50]
    err = folds.mean(axis=1)
    se = folds.std(axis=1, ddof=1) / 2.0
    best = int(np.argmin(err))
    expected = min((c, e, i) for i, (c, e) in enumerate(zip(complexity, err)) if e <= err[best] + se[best])[2]
    assert expected == 1
    order = np.argsort(err)
    tb = {k: v[order] for k, v in _table(err, se, complexity).items()}
    assert order[select_one_se(tb)] == expected
    # a larger SE of the best widens the set to the 3-term model C
    tb["pos_err_5s_se_m"][0] = 0.6
    assert order[select_one_se(tb)] == 2


def test_unstable_or_diverging_models_are_never_selected():
    tb = _table([1.0, 1.01, 1.2, 1.3], [0.2, 0.2, 0.2, 0.2], [5, 2, 1, 40],
                stable=[True, False, True, True], diverged=[0.0, 0.0, 0.1, 0.0])
    assert list(admissible(tb)) == [True, False, False, True]
    assert select_one_se(tb) == 0  # the sparser rows 1 and 2 are inadmissible
    assert select_parsimonious(tb, 0.5) == 0


def test_search_flags_a_model_unstable_at_rest(runs):
    """A single grid point with T = 0 and no ridge on 2 s windows: compare the flag with eigvals of J_f_x(0, 0)."""
    grid = SearchGrid(s=(0.0,), tau=(2.0,), alpha=(0.0,), T=(0.0, 0.2), n_folds=2)
    res = search({0.0: runs}, grid, names=list("abcd"), n_top=2)
    for i in range(2):
        hp = res.row(i)
        fold = fold_assignment(np.arange(4), 2)
        worst = -np.inf
        for f in (0, 1):
            m = fit_sindy([r for r, g in zip(runs, fold) if g != f], tau=2.0, alpha=hp["alpha"], threshold=hp["T"])
            worst = max(worst, np.linalg.eigvals(m.J_f_x(np.zeros(3), np.zeros(2))).real.max())
        assert hp["max_re_eig_rest"] == pytest.approx(worst, rel=1e-6, abs=1e-9)
        assert hp["stable_at_rest"] == (worst <= 1e-9)
    # the true model is stable at rest: eigenvalues -5, -4, -6
    assert res.row(res.selected)["stable_at_rest"] and res.row(res.selected)["max_re_eig_rest"] < -3


def test_search_ranks_a_model_that_blows_up_last(runs, monkeypatch):
    """Force one candidate to run away (coefficients replaced by an unstable linear law) and check the ranking."""
    import identification.sindy.search as search_mod

    real = search_mod.fit_stlsq

    def fake(r, c, threshold, alpha, **kw):
        coef = real(r, c, threshold, alpha, **kw)
        if threshold == 0.2:
            coef = np.zeros_like(coef)
            coef[:, 1:4] = 5.0 * np.eye(3)  # x_dot = +5 x: unstable, grows e^25 in 5 s
        return coef

    monkeypatch.setattr(search_mod, "fit_stlsq", fake)
    grid = SearchGrid(s=(0.0,), tau=(2.0,), alpha=(0.05,), T=(0.2, 2.0), n_folds=2)
    res = search({0.0: runs}, grid, names=list("abcd"), n_top=1)
    last = res.row(1)
    assert last["T"] == 0.2 and last["diverged_frac"] > 0.5 and not last["stable_at_rest"]
    assert res.selected == 0


def test_normalised_fit_is_scale_free_and_equals_the_full_problem(runs):
    """Scaling a feature column or a target leaves the normalised selection unchanged; compressed == full."""
    from identification.sindy.regression import fit_stlsq, integral_problem

    problem = integral_problem(runs, "poly2", tau=1.0)
    r, c = problem.compressed()
    full = fit_stlsq(problem.theta_int, problem.delta_x, 0.05, 1e-3, normalize=True)
    np.testing.assert_allclose(fit_stlsq(r, c, 0.05, 1e-3, normalize=True), full, rtol=1e-6, atol=1e-9)
    scale_col = np.ones(r.shape[1])
    scale_col[3] = 1e3  # a feature in other units
    scale_tgt = np.array([1.0, 1e-3, 10.0])  # equations in other units
    scaled = fit_stlsq(r * scale_col, c * scale_tgt, 0.05, 1e-3, normalize=True)
    np.testing.assert_allclose(scaled, full * scale_tgt[:, None] / scale_col[None, :], rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("argv, culprit", [
    (["--out", "{blocker}/m.json"], "{blocker}"),
    (["--out", "{tmp}/m.json", "--json", "{blocker}/s.json"], "--json"),
    (["--out", "{tmp}/m.json", "--tau", "0", "1"], "--tau"),
    (["--out", "{tmp}/m.json", "--library", "poly9"], "poly9"),
])
def test_identify_checks_its_options_before_reading_the_campaign(argv, culprit, tmp_path, capsys):
    """A missing campaign would fail too: the option's error must come first (nothing was searched)."""
    from sindy_ekf.cli import main

    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    fill = {"blocker": str(blocker), "tmp": str(tmp_path)}
    args = ["identify", str(tmp_path / "no_campaign")] + [a.format(**fill) for a in argv] + ["--quiet"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and culprit.format(**fill) in err[0], err
