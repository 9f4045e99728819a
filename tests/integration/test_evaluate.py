"""``wheelchair-hil evaluate`` end to end on tiny campaigns: the same results in this process,
in a pool of worker processes and on a Dask cluster of two worker processes; the outputs it
writes."""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from controller.limits import RATE_LIMITS
from tools.cli import main
from tools.evaluation import plan
from tools.evaluation.assemble import deterministic_part
from tools.evaluation.campaign import Options, plan_campaign
from tools.evaluation.execute import groups
from tools.evaluation.pipeline import evaluate

# make test starts the heaviest files first (tests/conftest.py)
pytestmark = pytest.mark.heavy(seconds=34)

#: Four runs of 3 simulated seconds: the start of the paper route, no fault, in two fault
#: settings ((a) paper without a flat tire is the physical run).
TINY = Options(
    controllers=("antifragile", "baseline"),
    scenarios=("fault-free",),
    cascaded=False,
    duration_s=3.0,
    settings=("paper", "diagnosed"),
)
PNG = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def inline(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, dict[str, Any]]]:
    out = tmp_path_factory.mktemp("inline")
    yield out, evaluate(TINY, out, workers=1, progress=False)


def test_a_campaign_writes_results_report_figures_and_every_log(
    inline: tuple[Path, dict[str, Any]],
) -> None:
    out, results = inline
    on_disk = json.loads((out / "results.json").read_text())
    assert on_disk == json.loads(json.dumps(results))
    assert not results["meta"]["failed_runs"]
    for c in ("antifragile", "baseline"):
        cell = results["table"][c]["fault-free"]
        assert 0.0 < cell["rmse_pos_m"] < 0.05
        assert cell["comfort_av_mps2"] > 0.0
        assert (out / cell["log"]).stat().st_size > 0
        assert results["timing"]["table"][c]["fault-free"]["controller_step_us_p50"] > 0
        shares = cell["rate_limit_share"]
        assert set(shares) == set(RATE_LIMITS) and all(0.0 <= v <= 1.0 for v in shares.values())
        assert results["settings"]["paper"]["limit_use"][c]["runs"] == 1
        assert results["settings"]["paper"]["limit_use"][c]["stopped"] == 0  # a fault-free run
    assert results["rank"]["rmse_xe_m"]["antifragile"]["rank"] == 1  # the only ranked one
    assert "baseline" not in results["rank"]["rmse_xe_m"]
    assert results["meta"]["setting"] == "paper" and set(results["settings"]) == {
        "paper",
        "diagnosed",
    }
    assert results["table"]["baseline"]["fault-free"]["fault_setting"] == "physical"
    assert results["meta"]["runs"] == 4
    for name in (
        "fig09_trajectories.png",
        "fig10_antifragile_twist.png",
        "fig11_antifragile_errors.png",
    ):
        assert (out / name).read_bytes()[:8] == PNG, name
    report = (out / "report.md").read_text()
    assert "| ANTIFRAGILE | " in report and "(0.0025)" in report
    assert "![fig09_trajectories.png](fig09_trajectories.png)" in report
    assert "## Fault setting (a) paper" in report and "## Fault setting (c) diagnosed" in report
    assert report.count("### How each law met the envelope, and what it did") == 2
    # two controllers are not the paper's four: no overall agreement count is claimed
    assert "not comparable with the paper's" in report and "Overall" not in report


def test_each_runs_summary_is_the_one_summarize_computes_from_its_log(
    inline: tuple[Path, dict[str, Any]],
) -> None:
    """The evaluation reads a run's log once, while it is merged; what it keeps must be the
    whole summary, not only the channels its own series need."""
    from tools.logs import runlog

    out, results = inline
    for c in ("antifragile", "baseline"):
        log = out / results["table"][c]["fault-free"]["log"]
        written = json.loads((log.parent / "summary.json").read_text())
        again = json.loads(json.dumps(runlog.summarize(log), default=str))
        assert written["fault_diagnosis"]["samples"] > 0
        assert written["frames_total"] > 0 and written["control_effort"] > 0
        for key, value in again.items():
            if key not in ("wall_total_s", "bus"):
                assert written[key] == value, key


def test_a_process_pool_gives_the_same_results_as_one_process(
    inline: tuple[Path, dict[str, Any]], tmp_path: Path, resource_tracker: None
) -> None:
    pooled = evaluate(TINY, tmp_path, workers=2, progress=False, figures=False, report=False)
    assert "2 worker process(es)" in pooled["timing"]["executor"]
    assert deterministic_part(pooled) == deterministic_part(inline[1])


#: Monte-Carlo replicates of three scenarios that differ only in their faults (from 20 s):
#: the pool runs each replicate as one run branched before the faults (tools.run.branches)
SHARED = Options(
    controllers=("robust",),
    scenarios=("fault-free", "bump-left", "flat-left"),
    seeds=2,
    cascaded=False,
    duration_s=22.0,
    settings=("physical",),
)


def test_replicates_that_share_their_start_give_the_results_of_runs_made_one_by_one(
    tmp_path: Path, resource_tracker: None
) -> None:
    camp = plan_campaign(SHARED)
    units = groups(list(camp.tasks.values()), SHARED.scenarios)
    assert sorted(len(u) for u in units) == [1, 1, 1, 3, 3]  # nominal (logged) runs alone
    one_by_one = evaluate(
        SHARED, tmp_path / "inline", workers=1, progress=False, figures=False, report=False
    )
    shared = evaluate(
        SHARED, tmp_path / "pool", workers=2, progress=False, figures=False, report=False
    )
    assert not shared["meta"]["failed_runs"]
    assert deterministic_part(shared) == deterministic_part(one_by_one)
    assert not (tmp_path / "pool" / "runs" / ".branches").exists()


def _dask_cluster(tmp: Path, workers: int) -> tuple[str, list[subprocess.Popen[bytes]]]:
    """A Dask cluster as a user starts one (docs/evaluation.md, "Beyond one machine"): the
    ``dask scheduler`` command and ``workers`` ``dask worker`` processes of one thread each
    (without a nanny: each command is its worker, so terminating it leaves no process)."""
    dask = Path(sys.executable).with_name("dask")
    info = tmp / "scheduler.json"
    procs = [
        subprocess.Popen(
            [
                dask,
                "scheduler",
                "--host",
                "127.0.0.1",
                "--port",
                "0",
                "--no-dashboard",
                "--scheduler-file",
                info,
            ],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    deadline = time.monotonic() + 60
    while not info.exists() and time.monotonic() < deadline:
        time.sleep(0.2)
    address = json.loads(info.read_text())["address"]
    for _ in range(workers):
        procs.append(
            subprocess.Popen(
                [
                    dask,
                    "worker",
                    address,
                    "--nthreads",
                    "1",
                    "--no-nanny",
                    "--no-dashboard",
                    "--host",
                    "127.0.0.1",
                ],
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
        )
    from distributed import Client  # lazy: the optional [dask] extra

    with Client(address, timeout=60) as client:
        client.wait_for_workers(workers, timeout=60)
    return address, procs


@pytest.mark.skipif(
    importlib.util.find_spec("distributed") is None,
    reason="dask.distributed is not installed (optional extra: pip install '.[dask]')",
)
def test_a_dask_cluster_of_two_worker_processes_gives_the_pools_results(
    inline: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    """The same results.json as one process, which the pool's is too (the test above)."""
    address, procs = _dask_cluster(tmp_path, workers=2)
    try:
        remote = evaluate(
            TINY,
            tmp_path / "dask",
            scheduler=address,
            progress=False,
            figures=False,
            report=False,
        )
    finally:
        for p in procs:  # a cluster made for this test: nothing to shut down gracefully
            p.kill()
            p.wait()
    assert remote["timing"]["executor"] == f"dask {address}"
    assert not remote["meta"]["failed_runs"]
    assert deterministic_part(remote) == deterministic_part(inline[1])
    assert (
        tmp_path
        / "dask"
        / "runs"
        / "physical"
        / "fault-free"
        / "nominal"
        / "baseline"
        / "series.npz"
    ).exists()


def test_the_command_refuses_an_unknown_controller_before_running_anything(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["evaluate", "--out", str(tmp_path), "--controllers", "robust,nope"])
    assert rc == 2
    assert "unknown controller 'nope'" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists()


def test_resume_reuses_the_runs_already_made_for_the_same_tasks(
    inline: tuple[Path, dict[str, Any]], tmp_path: Path
) -> None:
    import shutil

    shutil.copytree(inline[0] / "runs", tmp_path / "runs")
    again = evaluate(TINY, tmp_path, progress=False, figures=False, report=False, resume=True)
    assert all(t["resumed"] for t in again["timing"]["runs"].values())
    assert deterministic_part(again) == deterministic_part(inline[1])


def test_a_spectrum_campaign_classifies_and_draws_the_measured_spectrum(tmp_path: Path) -> None:
    """Five 2 s runs (no fault is active yet, so the response is flat): the sweep is planned,
    κ is computed and classed, and the spectrum figure is drawn."""
    opt = Options(
        controllers=("baseline",),
        scenarios=("fault-free",),
        cascaded=False,
        spectrum=True,
        spectrum_faults=("flat-right",),
        spectrum_seeds=1,
        duration_s=2.0,
    )
    results = evaluate(opt, tmp_path, workers=1, progress=False)
    cell = results["spectrum"]["baseline"]["flat-right"]
    assert len(cell["response"][0]) == len(plan.SPECTRUM_FACTORS)
    assert cell["class"] == "robust" and abs(cell["kappa"]) < plan.SPECTRUM_TOLERANCE
    assert (tmp_path / "fig01_spectrum.png").read_bytes()[:8] == PNG
    assert "## The spectrum, measured" in (tmp_path / "report.md").read_text()
