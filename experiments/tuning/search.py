"""The searches over (q, r): a log grid through ``experiments.sweep`` and an optuna TPE study
(``experiments.tuning``)."""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from experiments.tuning.filter import margin_columns
from experiments.tuning.objective import (
    SEED_Q_SCALE,
    SEED_R_SCALE,
    TuningObjective,
    _ratio,
    _rows_of,
    _run_configs,
    aggregate,
    evaluate,
)
from latency import Engine

# --------------------------------------------------------------------------------------------
# Grid search
# --------------------------------------------------------------------------------------------


def log_grid(center: float, n: int, decades: float) -> NDArray[np.float64]:
    """``n`` log-spaced values from ``center·10^-decades`` to ``center·10^decades``; ``center``
    itself is always included (exactly), so the seed's value is a grid point."""
    if n < 1 or center <= 0 or decades < 0:
        raise ValueError(f"need n >= 1, center > 0, decades >= 0; got {n}, {center}, {decades}")
    vals = center * 10.0 ** np.linspace(-decades, decades, n) if n > 1 else np.array([center])
    vals = np.where(np.isclose(vals, center, rtol=1e-12), center, vals)
    return np.unique(np.append(vals, center))


def grid_search(
    objectives: TuningObjective | Sequence[TuningObjective],
    q_values: Sequence[float],
    r_values: Sequence[float],
    out_dir: str | Path,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool = True,
    margins: bool = True,
    engine: Engine = "batched",
) -> pd.DataFrame:
    """Mean closed-loop cost on the grid ``q_values × r_values`` for each objective (delay).

    All runs go through ``experiments.sweep.run_sweep`` into ``out_dir/runs`` (resumable; local
    process pool, ``scheduler="local"`` for a Dask LocalCluster, or a Dask address; with
    ``workers=1`` and no scheduler the same runs and files are made in this process), on the
    batched engine or, with ``engine="event"``, the event loop.

    Returns one row per (delay, q, r): ``delay_s, q, r, q_over_r, n_runs, n_failed, cost``
    (deg), ``cost_sem``, the cost terms and metrics (see ``run_cost``), ``is_seed`` and, with
    ``margins``, the columns of ``margin_columns`` (loop with the steady-state filter).
    """
    objs = [objectives] if isinstance(objectives, TuningObjective) else list(objectives)
    configs = [c for o in objs for q in q_values for r in r_values for c in o.configs(q, r)]
    out = Path(out_dir)
    _run_configs(configs, out, scheduler, workers, progress, engine)
    table = aggregate(_rows_of(configs, out))
    table["is_seed"] = np.isclose(table.q, SEED_Q_SCALE) & np.isclose(table.r, SEED_R_SCALE)
    if margins:
        by_delay = {float(o.delay_s): o for o in objs}
        extra = [
            margin_columns(by_delay[float(row.delay_s)], row.q, row.r) for row in table.itertuples()
        ]
        table = pd.concat([table, pd.DataFrame(extra)], axis=1)
    return table


# --------------------------------------------------------------------------------------------
# optuna
# --------------------------------------------------------------------------------------------


def study_name_for(objective: TuningObjective) -> str:
    """Default study name: one study per delay (several delays can share one storage file)."""
    return f"kalman-qr-{objective.delay_s * 1e3:.2f}ms"


def _study(storage: str, name: str, sampler_seed: int):
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    return optuna.create_study(
        storage=_storage(storage),
        study_name=name,
        direction="minimize",
        sampler=optuna.samplers.TPESampler(seed=sampler_seed),
        load_if_exists=True,
    )


def _storage(url: str):
    """SQLite with a generous lock timeout, so that several workers can share one file."""
    import optuna

    if url.startswith("sqlite:"):
        return optuna.storages.RDBStorage(url, engine_kwargs={"connect_args": {"timeout": 60}})
    return url


def _optuna_worker(
    objective_json: str,
    storage: str,
    name: str,
    n_trials: int,
    sampler_seed: int,
    bounds: tuple[float, float, float, float],
    cache_dir: str | None,
    progress: bool = False,
    engine: Engine = "batched",
) -> int:
    """Run trials of one study until it has ``n_trials`` complete ones; returns how many this
    worker ran."""
    import optuna
    from optuna.trial import TrialState

    objective = TuningObjective.model_validate_json(objective_json)
    study = _study(storage, name, sampler_seed)
    q_lo, q_hi, r_lo, r_hi = bounds
    done = len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)))
    todo = n_trials - done
    if todo <= 0:
        return 0
    ran = 0

    def fn(trial) -> float:
        nonlocal ran
        ran += 1
        q = trial.suggest_float("q", q_lo, q_hi, log=True)
        r = trial.suggest_float("r", r_lo, r_hi, log=True)
        res = evaluate(objective, q, r, cache_dir, engine=engine)
        for k in (
            "rms_error_deg",
            "mean_square_torque_N2m2",
            "n_lost_frames",
            "diverged",
            "cost_sem",
            "n_failed",
        ):
            trial.set_user_attr(k, float(res[k]))
        if not np.isfinite(res["cost"]):
            raise RuntimeError(f"a run failed at q={q:.4g}, r={r:.4g}")
        return float(res["cost"])

    study.optimize(
        fn,
        n_trials=todo,
        callbacks=[optuna.study.MaxTrialsCallback(n_trials, states=(TrialState.COMPLETE,))],
        catch=(RuntimeError,),
        show_progress_bar=progress,
    )
    return ran


def optuna_search(
    objective: TuningObjective,
    out_dir: str | Path,
    n_trials: int,
    *,
    storage: str | None = None,
    study_name: str | None = None,
    sampler_seed: int = 0,
    q_bounds: tuple[float, float] = (1e-4, 1.0),
    r_bounds: tuple[float, float] = (1e-3, 10.0),
    workers: int = 1,
    enqueue_seed_point: bool = True,
    progress: bool = False,
    engine: Engine = "batched",
):
    """TPE search of (q, r) on the objective; returns the ``optuna.Study``.

    The study lives in ``storage`` (default ``sqlite:///<out_dir>/optuna.db``) and is loaded if
    it exists, so calling again resumes it: ``n_trials`` is the number of *complete* trials the
    study should have, and only the missing ones run (with several workers, trials already in
    flight when the budget is reached still finish, so a study may end one or two over it;
    ``progress`` shows optuna's bar with one worker). Several processes (``workers``) or
    machines (the same ``storage`` URL) can work on one study. The TPE sampler is seeded
    (``sampler_seed``; worker i uses ``sampler_seed + i``): with one worker a fresh study is
    reproducible. The seed's (0.01, 0.1) is enqueued as the first trial of a new study. Runs
    are cached in ``out_dir/runs`` (shared with ``grid_search``); ``engine`` runs each trial's
    runs on the batched engine or the event loop.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    url = storage or f"sqlite:///{(out / 'optuna.db').resolve()}"
    name = study_name or study_name_for(objective)
    study = _study(url, name, sampler_seed)
    if enqueue_seed_point and len(study.trials) == 0:
        study.enqueue_trial({"q": SEED_Q_SCALE, "r": SEED_R_SCALE})
    bounds = (*q_bounds, *r_bounds)
    args = (objective.model_dump_json(), url, name, n_trials)
    if workers <= 1:
        _optuna_worker(*args, sampler_seed, bounds, str(out), progress, engine)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futs = [
                pool.submit(_optuna_worker, *args, sampler_seed + i, bounds, str(out), False,
                            engine)
                for i in range(workers)
            ]
            for f in futs:
                f.result()
    return _study(url, name, sampler_seed)


def trials_table(study, delay_s: float) -> pd.DataFrame:
    """Complete trials of a study: ``delay_s, trial, q, r, q_over_r, cost`` and user attrs."""
    from optuna.trial import TrialState

    rows = []
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        row = {"delay_s": delay_s, "trial": t.number, "q": t.params["q"], "r": t.params["r"]}
        row["q_over_r"] = _ratio(row["q"], row["r"])
        row["cost"] = t.value
        row.update(t.user_attrs)
        rows.append(row)
    return pd.DataFrame(rows)
