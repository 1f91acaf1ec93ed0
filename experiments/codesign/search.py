"""The co-design search: a multi-objective optuna study over the spec's design space.

Objectives (all minimised): the mean RMS attitude error over the Monte-Carlo runs (deg), the
control effort (mean RMS torque, N·m) and the compute per processed frame (s). Constraints
(``Constraints``): critical phase margin and delay headroom from the exact analysis
(``experiments.codesign.analysis``), probability of loss of control and lost-frame fraction from
Monte Carlo (``experiments.codesign.evaluate``).

The study runs by ask-and-tell in batches of ``search.batch_size`` designs: each design is
analysed first, and one whose linear loop is unstable beyond ``search.prune_growth_rate_per_s``
(``Analysis.prunable``) is *pruned*: no Monte Carlo, its analysis kept. The others' runs go to
the batched engine together, those failing the analysis constraints included (they are
infeasible whatever their Monte Carlo, but skipping it could skip a design the Monte Carlo
accepts). The sampler sees only the designs that meet the analysis constraints as complete
trials; the rest are told to optuna as pruned (their records keep their Monte Carlo), so that
NSGA-II's populations hold only designs meeting the requirements (docs/codesign.md, "Pruning",
measures the search both ways). NSGA-II or TPE read the constraints each
trial sets (``Trial.set_constraint``; <= 0 is feasible).

The study is stored in SQLite in the output folder by default, so that a rerun resumes it: it
stops once ``search.n_trials`` trials are finished (complete or pruned). A rerun treats trials
left running by an interrupted run as failed and asks their designs again (their finished runs
come from the run cache). Several workers (processes, or a Dask cluster) share one study; each
asks its own batches (so a shared study may end a few trials over its budget: the workers'
last batches overlap).
"""

from __future__ import annotations

import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

from tqdm import tqdm

from experiments.codesign.analysis import Analysis, analyse
from experiments.codesign.evaluate import mc_excess, mc_feasible, monte_carlo
from experiments.codesign.space import Design, compute_per_frame_s, suggest
from experiments.codesign.spec import CodesignSpec

if TYPE_CHECKING:
    import optuna

#: Objective names, in the study's order.
OBJECTIVES = ("rms_error_deg", "rms_torque_Nm", "compute_per_frame_s")
#: Constraint names, in ``constraint_values``' order.
CONSTRAINTS = ("phase_margin", "delay_headroom", "loss_of_control", "lost_frames")
#: Seconds between two looks at the shared study while workers run (progress bar).
POLL_S = 2.0


def storage_url(spec: CodesignSpec, out_dir: Path) -> str:
    """The study's storage: the spec's, or SQLite in ``out_dir``."""
    return spec.search.storage or f"sqlite:///{(out_dir / 'codesign.db').resolve()}"


def _storage(url: str):
    """SQLite with a generous lock timeout, so that several workers can share one file."""
    import optuna

    if url.startswith("sqlite:"):
        return optuna.storages.RDBStorage(url, engine_kwargs={"connect_args": {"timeout": 60}})
    return url


def open_study(spec: CodesignSpec, url: str, worker: int = 0) -> optuna.Study:
    """The spec's study (created or loaded), its sampler seeded with ``search.seed + worker``."""
    import optuna

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    seed = spec.search.seed + worker
    if spec.search.sampler == "nsga2":
        sampler = optuna.samplers.NSGAIISampler(
            population_size=max(spec.search.batch_size, 2), seed=seed)
    else:
        sampler = optuna.samplers.TPESampler(seed=seed, multivariate=True)
    return optuna.create_study(
        storage=_storage(url), study_name=spec.search.study_name or spec.name,
        directions=["minimize"] * len(OBJECTIVES), sampler=sampler, load_if_exists=True)


def n_finished(study: optuna.Study) -> int:
    """Trials finished: complete or pruned."""
    from optuna.trial import TrialState

    return len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))


def constraint_values(spec: CodesignSpec, a: Analysis, mc: dict | None) -> list[float]:
    """The constraints as optuna reads them (<= 0 feasible): phase margin, headroom, loss of
    control, lost frames; the Monte-Carlo ones are 1 when there is no Monte Carlo."""
    c = spec.constraints
    pm = a.phase_margin_deg if a.stable else -180.0
    out = [c.min_phase_margin_deg - pm, c.min_delay_headroom_ms - 1e3 * a.headroom_s]
    if mc is None:
        return out + [1.0, 1.0]
    return out + list(mc_excess(spec, mc))


def evaluate_designs(
    spec: CodesignSpec, designs: list[Design], out_dir: Path, prune: bool = True
) -> list[dict]:
    """Analysis, then Monte Carlo for the designs it does not prune (``Analysis.prunable``;
    all of them when not ``prune``). Returns per design a record: ``design`` (dict),
    ``analysis`` (dict), ``pruned`` (no Monte Carlo), ``meets_analysis``, ``mc`` (dict or
    None), ``objectives`` (list or None), ``constraints`` and ``feasible``."""
    analyses = [analyse(spec, d) for d in designs]
    keep = [i for i, a in enumerate(analyses) if not (prune and a.prunable(spec))]
    mcs = monte_carlo(spec, [designs[i] for i in keep], out_dir)
    mc_of = dict(zip(keep, mcs, strict=True))
    out = []
    for i, (d, a) in enumerate(zip(designs, analyses, strict=True)):
        mc = mc_of.get(i)
        rec = {"design": d.model_dump(mode="json"), "analysis": a.__dict__, "pruned": mc is None,
               "meets_analysis": a.meets(spec), "mc": mc, "objectives": None,
               "constraints": constraint_values(spec, a, mc)}
        if mc is not None:
            rec["objectives"] = [mc["rms_error_deg"], mc["rms_torque_Nm"],
                                 compute_per_frame_s(spec, d)]
        rec["feasible"] = mc is not None and a.meets(spec) and mc_feasible(spec, mc)
        out.append(rec)
    return out


def _retry_interrupted(study: optuna.Study) -> None:
    """Trials left running by an interrupted run: marked failed, their designs asked again."""
    from optuna.trial import TrialState

    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study._storage.set_trial_state_values(t._trial_id, state=TrialState.FAIL)
        if t.params:
            study.enqueue_trial(t.params, skip_if_exists=True)


def search_worker(spec_json: str, out: str, url: str, worker: int = 0,
                  progress: bool = False) -> int:
    """Ask, evaluate and tell batches until the study has ``search.n_trials`` finished trials;
    returns how many this worker told."""
    from optuna.trial import TrialState

    spec = CodesignSpec.model_validate_json(spec_json)
    out_dir = Path(out)
    study = open_study(spec, url, worker)
    told = 0
    bar = tqdm(total=spec.search.n_trials, initial=min(n_finished(study), spec.search.n_trials),
               desc="designs", unit="design", disable=not progress)
    try:
        while (left := spec.search.n_trials - n_finished(study)) > 0:
            trials = [study.ask() for _ in range(min(spec.search.batch_size, left))]
            designs = [suggest(t, spec) for t in trials]
            for t, rec in zip(trials, evaluate_designs(spec, designs, out_dir), strict=True):
                for k in ("design", "analysis", "mc", "objectives", "constraints", "feasible"):
                    t.set_user_attr(k, rec[k])
                for name, value in zip(CONSTRAINTS, rec["constraints"], strict=True):
                    t.set_constraint(name, value)
                if rec["pruned"] or not rec["meets_analysis"]:
                    study.tell(t, state=TrialState.PRUNED)
                else:
                    study.tell(t, rec["objectives"])
                told += 1
                bar.update(1)
    finally:
        bar.close()
    return told


def run_search(
    spec: CodesignSpec,
    out_dir: Path,
    workers: int = 1,
    scheduler: str | None = None,
    progress: bool = True,
) -> optuna.Study:
    """Run (or resume) the study in ``out_dir``; returns it. ``workers`` processes share it
    (this process alone when 1), or the workers of a Dask cluster (``scheduler``: ``"local"``
    for a LocalCluster of ``workers`` processes, or a scheduler address)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "spec.json").write_text(spec.model_dump_json(indent=1) + "\n")
    url = storage_url(spec, out_dir)
    study = open_study(spec, url)
    _retry_interrupted(study)
    args = (spec.model_dump_json(), str(out_dir), url)
    if scheduler is None and workers <= 1:
        search_worker(*args, 0, progress)
        return study
    if scheduler is None:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = [pool.submit(search_worker, *args, i) for i in range(workers)]
            _wait(futures, study, spec, progress)
        return study
    from dask.distributed import Client, LocalCluster

    cluster = (LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                            dashboard_address=None) if scheduler == "local" else None)
    client = Client(cluster if cluster is not None else scheduler)
    try:
        n = workers if scheduler == "local" else len(client.scheduler_info()["workers"]) or 1
        futures = [client.submit(search_worker, *args, i, pure=False) for i in range(n)]
        _wait(futures, study, spec, progress)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return study


def _wait(futures: list, study: optuna.Study, spec: CodesignSpec, progress: bool) -> None:
    """Wait for the workers, showing the study's finished trials; re-raise a worker's error."""
    with tqdm(total=spec.search.n_trials, desc="designs", unit="design",
              disable=not progress) as bar:
        while not all(f.done() for f in futures):
            time.sleep(POLL_S)
            bar.n = min(n_finished(study), spec.search.n_trials)
            bar.refresh()
        for f in futures:
            f.result()
        bar.n = min(n_finished(study), spec.search.n_trials)
        bar.refresh()


def trial_records(study: optuna.Study) -> list[dict]:
    """The finished trials as records (``evaluate_designs``'s, plus ``trial``)."""
    from optuna.trial import TrialState

    out = []
    for t in study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)):
        rec = {k: t.user_attrs.get(k) for k in ("design", "analysis", "mc", "objectives",
                                                 "constraints", "feasible")}
        rec["trial"] = t.number
        rec["pruned"] = rec["mc"] is None
        if t.values:  # a complete trial: the objectives optuna holds
            rec["objectives"] = list(t.values)
        out.append(rec)
    return out

