"""Hyperparameter search (thesis 5.3.6): run-grouped folds, ranking by local-frame 5 s error
checked against an independent evaluation, recovery of the known model, the batched scoring of
all (alpha, T) against one model at a time, and the identify/evaluate commands end to end."""

from __future__ import annotations

import json

import numpy as np
import pytest

from identification.evaluate import errors_from_rollout, evaluate_model, make_windows, rollout
from identification.model import SindyModel, model_from_terms
from identification.search import SearchGrid, StackedSindy, fold_assignment, plot_grid, search
from identification.sindy import fit_sindy
from sindy_ekf.errors import InputError
from sindy_synth import SPARSE_TERMS, simulate_states

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


@pytest.mark.filterwarnings("ignore::identification.model.EnvelopeWarning")  # a held-out run is a bit wider
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
def test_identify_and_evaluate_commands_end_to_end(small_trajectory, tmp_path):
    from sindy_ekf.cli import main

    model_path, id_json, ev_json = tmp_path / "m.json", tmp_path / "id.json", tmp_path / "ev.json"
    assert main(["identify", str(small_trajectory), "--out", str(model_path), "--quick", "--quiet",
                 "--json", str(id_json)]) == 0
    model = SindyModel.load(model_path)
    assert json.loads(id_json.read_text())["complexity"] == model.complexity > 0
    assert main(["evaluate", str(small_trajectory), "--model", str(model_path), "--quiet",
                 "--json", str(ev_json)]) == 0
    ev = json.loads(ev_json.read_text())
    assert ev["n_windows"] > 0 and 0 < ev["pos_err_5s_m"] < ev["baselines"]["constant_velocity"]["pos_err_5s_m"]
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
