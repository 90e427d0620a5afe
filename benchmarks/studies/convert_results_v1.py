"""One-off: the pre-schema result files (and tables measured without one) to schema 1.

Ran once; kept as the record of where every recovered field came from. Reads the old files
from git at commit db547ff (so it still runs after they are gone) and writes
``benchmarks/results/*.json`` (schema: ``benchmarks/results_io.py``). Figures are copied
as they were; what the old files lacked (machine, commit, versions, command, date) comes
from the commit that added each file and from the text of RESULTS.md / NOTES.md at the
time, and is listed in each file's ``recovered``. Tables that had no result file but whose
command the text names were entered from RESULTS.md's figures (``recovered.rows``).

    python benchmarks/studies/convert_results_v1.py
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))  # benchmarks/
import results_io  # noqa: E402

OLD = "db547ff"
ADDED = "the commit that added the file"
MEASURED_BEFORE = "the commit that added the file; measured on the tree just before it"

DEV2: dict[str, Any] = {
    "description": "the shared 2-core development machine",
    "cpu": "x86_64",
    "cores": 2,
    "gpu": None,
    "host": "vm",
    "backend": "cpu",
    "device_count": 1,
}
CPU16: dict[str, Any] = {
    "description": "the 16-core CPU of a lent GPU host, JAX_PLATFORMS=cpu",
    "cpu": "x86_64",
    "cores": 16,
    "gpu": None,
    "host": "vm",
    "backend": "cpu",
}
PINNED2: dict[str, Any] = {
    "description": "an idle 16-core x86-64 host, the process pinned to 2 cores "
    "(taskset -c 0,1, JAX_PLATFORMS=cpu)",
    "cpu": "x86_64",
    "cores": 2,
    "gpu": None,
}
H100: dict[str, Any] = {
    "description": "one NVIDIA H100 80GB HBM3",
    "cpu": "x86_64",
    "cores": 16,
    "gpu": "NVIDIA H100 80GB HBM3",
    "host": "vm",
    "backend": "gpu",
    "device_count": 1,
}
H200: dict[str, Any] = {
    "description": "one NVIDIA H200",
    "cpu": "x86_64",
    "cores": 16,
    "gpu": "NVIDIA H200",
    "backend": "gpu",
}
H200X2: dict[str, Any] = {
    "description": "2 x NVIDIA H200 of one host",
    "cpu": "x86_64",
    "cores": None,
    "gpu": "2 x NVIDIA H200",
    "host": "vm",
    "backend": "gpu",
    "device_count": 2,
}
#: the 2-core machine's peer versions, as RESULTS.md stated them for its runs
DEV2_PEERS = {"mujoco": "4.0.0", "envpool": "1.2.5", "gymnax": "1.0.1", "gymnasium": "1.4.0"}
GPU_HOST = {"python": "3.12.3", "jax": "0.11.2", "mujoco-mjx": "3.17.0"}


def old(name: str) -> Any:
    text = subprocess.run(
        ["git", "show", f"{OLD}:benchmarks/{name}.json"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    return json.loads(text)


def commit_date(sha: str) -> str:
    return subprocess.run(
        ["git", "show", "-s", "--format=%ad", "--date=format-local:%Y-%m-%dT%H:%M:%SZ", sha],
        capture_output=True,
        text=True,
        check=True,
        env={"TZ": "UTC", "PATH": "/usr/bin:/bin"},
    ).stdout.strip()


def rec(
    name: str,
    title: str,
    rows: list[dict[str, Any]],
    *,
    machine: dict[str, Any],
    sha: str,
    sha_how: str = ADDED,
    versions: dict[str, str],
    recovered_versions: tuple[str, ...] = (),
    command: str,
    command_how: str = "",
    date: str = "",
    date_how: str = "",
    machine_how: str = "",
    rows_how: str = "",
    engine: str | None = None,
    notes: str = "",
    extra: dict[str, Any] | None = None,
) -> None:
    recovered: dict[str, str] = {"commit": sha_how}
    if not date:
        date, date_how = commit_date(sha)[:10], "the date of " + ADDED
    recovered["date"] = date_how
    if machine_how:
        recovered["machine"] = machine_how
    for v in recovered_versions:
        recovered[f"versions.{v}"] = "RESULTS.md's text for this run"
    if command_how:
        recovered["command"] = command_how
    if rows_how:
        recovered["rows"] = rows_how
    out: dict[str, Any] = {
        "schema": results_io.SCHEMA,
        "name": name,
        "title": title,
        "machine": machine,
        "commit": f"{sha} (recovered: {sha_how})",
        "versions": versions,
        "command": command,
        "date": f"{date} (recovered)",
        "recovered": recovered,
    }
    if engine:
        out["engine"] = engine
    if notes:
        out["notes"] = notes
    out["rows"] = rows
    if extra:
        out["extra"] = extra
    results_io.write(name, out)


def bench_file(
    old_name: str,
    name: str,
    title: str,
    machine: dict[str, Any],
    sha: str,
    command: str,
    extra_versions: dict[str, str],
    **kw: Any,
) -> None:
    """A ``jaxenvs bench --json`` / ``peers.py --json`` file: rows as they were."""
    d = old(old_name)
    m = dict(machine)
    m["device_count"] = d["machine"]["device_count"]
    versions = {"python": d["machine"]["python"], "jax": d["machine"]["jax"], **extra_versions}
    extra = {k: v for k, v in d.items() if k not in ("machine", "results")}
    kw.setdefault("command_how", "RESULTS.md's text (the file's args, where it has them, agree)")
    rec(
        name,
        title,
        d["results"],
        machine=m,
        sha=sha,
        versions=versions,
        recovered_versions=tuple(extra_versions),
        command=command,
        extra=extra,
        **kw,
    )


def main() -> None:
    # --- both engines beside the peers, 2 and 16 cores (3094ab0) ------------------------
    c2 = "jaxenvs bench --tasks {} --modes full"
    bench_file(
        "cpu2_engines_cartpole_reacher",
        "engines_cpu2_cartpole_reacher",
        "CartPole-v0 and Reacher-v0 under MJX and C beside the peers, 2 cores",
        DEV2,
        "3094ab0",
        c2.format("CartPole-v0 Reacher-v0 --batches 256 4096 16384") + " --peers --repeats 5",
        DEV2_PEERS,
        sha_how=MEASURED_BEFORE,
        notes="load average 3-4 from other work; interleaved rounds, medians",
    )
    bench_file(
        "cpu2_engines_walker",
        "engines_cpu2_walker",
        "HexapodWalk-v0 under MJX and C beside the peers, 2 cores",
        DEV2,
        "3094ab0",
        c2.format("HexapodWalk-v0 --batches 256 --steps 20") + " --peers --repeats 5",
        DEV2_PEERS,
        sha_how=MEASURED_BEFORE,
        notes="load average 3-4 from other work; interleaved rounds, medians",
    )
    bench_file(
        "cpu2_engines_others",
        "engines_cpu2_cartpole_tasks_oneleg",
        "CartpoleStayUp, CartpoleBalance, CartpoleSwingup, HexapodOneLeg under MJX and C, 2 cores",
        DEV2,
        "3094ab0",
        c2.format(
            "CartpoleStayUp-v0 CartpoleBalance-v0 CartpoleSwingup-v0 HexapodOneLeg-v0 "
            "--batches 4096 --steps 50"
        )
        + " --repeats 3",
        {"mujoco": "4.0.0"},
        sha_how=MEASURED_BEFORE,
        notes="load average 3-4 from other work; interleaved rounds, medians",
    )
    c16 = "JAX_PLATFORMS=cpu jaxenvs bench --tasks {} --modes full --peers --repeats 3"
    spread = (
        "the default spread: MJX batches over 8 XLA host devices, the C engine and "
        "mujoco.rollout on 16 threads; the rows' devices field reads 1, a bench bug "
        "(fixed since) that did not report the spread; EnvPool and gymnax not installed"
    )
    bench_file(
        "cpu16_engines_cartpole_reacher",
        "engines_cpu16_cartpole_reacher",
        "CartPole-v0 and Reacher-v0 under MJX and C beside mujoco.rollout, 16 CPU cores",
        CPU16,
        "3094ab0",
        c16.format("CartPole-v0 Reacher-v0 --batches 16384 65536")
        + "   # from benchmarks/cpu_many_core.sh",
        {"mujoco": "4.0.0"},
        sha_how=MEASURED_BEFORE,
        notes=spread,
    )
    bench_file(
        "cpu16_engines_walker",
        "engines_cpu16_walker",
        "HexapodWalk-v0 under MJX and C beside mujoco.rollout, 16 CPU cores",
        CPU16,
        "3094ab0",
        c16.format("HexapodWalk-v0 --batches 1024 4096 --steps 20")
        + "   # from benchmarks/cpu_many_core.sh",
        {"mujoco": "4.0.0"},
        sha_how=MEASURED_BEFORE,
        notes=spread,
    )
    bench_file(
        "cpu16_walker_one_device",
        "engines_cpu16_walker_mjx_one_device",
        "HexapodWalk-v0 under MJX on one XLA CPU device, 16 CPU cores",
        CPU16,
        "3094ab0",
        "JAX_PLATFORMS=cpu XLA_FLAGS=--xla_force_host_platform_device_count=1 jaxenvs bench "
        "--tasks HexapodWalk-v0 --batches 1024 --steps 20 --modes full --physics mjx --repeats 3",
        {"mujoco": "4.0.0"},
        sha_how=MEASURED_BEFORE,
    )
    cold = (
        "rm -rf $JAXENVS_CACHE_DIR; jaxenvs train CartPole-v0 --algo ppo --no-video "
        "[--physics mjx]   # whole command, timed"
    )
    rec(
        "ppo_cartpole_cold_cpu2_engines",
        "Cold CartPole-v0 PPO, whole command, under C and MJX, 2 cores",
        [
            {"engine": "c", "load": "~1.7", "round": 1, "process_wall_s": 13.8},
            {"engine": "c", "load": "~1.7", "round": 2, "process_wall_s": 14.1},
            {"engine": "c", "load": "~1.7", "round": 3, "process_wall_s": 14.7},
            {"engine": "mjx", "load": "~1.7", "round": 1, "process_wall_s": 19.1},
            {"engine": "c", "load": "3-4", "round": 1, "process_wall_s": 19.0},
            {"engine": "mjx", "load": "3-4", "round": 1, "process_wall_s": 32.9},
        ],
        machine=DEV2,
        sha="001afe3",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.10.2", "mujoco": "4.0.0"},
        recovered_versions=("jax", "mujoco"),
        command=cold,
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures (no result file was written)",
        notes="an empty JAXENVS_CACHE_DIR before each run; same machine, same sequence",
    )
    rec(
        "ppo_cartpole_cold_cpu16_engines",
        "Cold CartPole-v0 PPO, whole command, under C and MJX, 16 CPU cores",
        [
            {"engine": "c", "devices": 1, "threads": 16, "process_wall_s": 18.7},
            {"engine": "mjx", "devices": 8, "process_wall_s": 25.9},
            {"engine": "mjx", "devices": 1, "process_wall_s": 19.3},
        ],
        machine=CPU16,
        sha="3094ab0",
        sha_how=MEASURED_BEFORE,
        versions={"python": "3.12.3", "jax": "0.11.2", "mujoco": "4.0.0"},
        recovered_versions=("python", "jax", "mujoco"),
        command="bash benchmarks/cpu_many_core.sh OUT   # jaxenvs train CartPole-v0 --algo ppo "
        "--no-video --no-compile-cache --quiet [--physics c | mjx | mjx --devices 1]",
        command_how="benchmarks/cpu_many_core.sh and RESULTS.md's text",
        rows_how="RESULTS.md's figures (the script's .txt output was not committed)",
    )
    d = old("cross_engine_cpu")
    rec(
        "cross_engine_ppo_cpu2",
        "Every CPU PPO config trained on the CPU default engine, evaluated under MJX and C",
        d,
        machine=dict(DEV2, load="2-4"),
        sha="3094ab0",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.10.2", "mujoco": "4.0.0"},
        recovered_versions=("jax", "mujoco"),
        command="python benchmarks/cross_engine.py --json benchmarks/cross_engine_cpu.json",
        command_how="RESULTS.md's text",
        notes="20 greedy episodes per engine, seed 0; wall times under load 2-4",
    )
    d = old("facade_reacher_cpu_default")
    r = d["results"][0]
    rows = []
    for mode in ("single", "vector"):
        for who, rounds in r[mode].items():
            rows.append(
                {
                    "task": r["task"],
                    "peer": r["peer"],
                    "mode": mode,
                    "who": who,
                    "num_envs": 1 if mode == "single" else r["num_envs"],
                    "steps_per_s_rounds": rounds,
                    "first_call_s": r["first_call_s"][mode] if who.startswith("ours") else None,
                }
            )
    rec(
        "facade_cpu2_reacher_c",
        "The Gymnasium facade on Reacher-v0 under the CPU default engine (C) against Reacher-v5",
        rows,
        machine=dict(DEV2, load="~1.5"),
        sha="4eebe50",
        sha_how=MEASURED_BEFORE,
        versions={**d["meta"] | {"mujoco": "4.0.0"}},
        recovered_versions=("mujoco",),
        command="python benchmarks/facade.py --tasks Reacher-v0 --num-envs 256 --rounds 5 "
        "--steps 2000 --json facade_reacher_cpu_default.json",
        command_how="RESULTS.md's text",
        engine="c",
    )
    # --- MJX throughput beside the peers, 2 cores (peers.py) ----------------------------
    peers = (
        "python benchmarks/peers.py --tasks {} --batches 4096 16384 --repeats 5 --json peers.json"
    )
    for i, (oldn, sha, when, state) in enumerate(
        [
            ("peers_cpu_lean_1", "2b106cf", "2026-11-23T19:28Z", "after the lean device model"),
            ("peers_cpu_lean_2", "2b106cf", "2026-11-23T19:31Z", "after the lean device model"),
            ("peers_cpu_final_1", "290f6ff", "2026-11-23T22:24Z", "after the reacher change"),
            ("peers_cpu_final_2", "290f6ff", "2026-11-23T22:31Z", "after the reacher change"),
        ],
        start=1,
    ):
        bench_file(
            oldn,
            f"peers_cpu2_cartpole_reacher_{i}",
            f"CartPole-v0 and Reacher-v0 (MJX) beside the peers, 2 cores, run {i} "
            f"({state}: NOTES.md)",
            dict(DEV2, load="quiet"),
            sha,
            peers.format("CartPole-v0 Reacher-v0"),
            DEV2_PEERS,
            sha_how=MEASURED_BEFORE,
            command_how="RESULTS.md's text",
            date=when,
            date_how="RESULTS.md's text (UTC time of the run)",
            engine="mjx",
        )
    for i, oldn in enumerate(("peers_cpu_reacher_1", "peers_cpu_reacher_2"), start=1):
        bench_file(
            oldn,
            f"peers_cpu2_reacher_{i}",
            f"Reacher-v0 (MJX) beside the peers, 2 cores, run {i} (after the reacher change)",
            dict(DEV2, load="quiet"),
            "290f6ff",
            peers.format("Reacher-v0"),
            DEV2_PEERS,
            sha_how=MEASURED_BEFORE,
            command_how="RESULTS.md's text",
            engine="mjx",
        )
    # --- GPU -----------------------------------------------------------------------------
    d = old("lean_model_h100")
    rows = []
    for key, run in d["runs"].items():
        rnd, lean, _task = key.split("_", 2)
        for row in run["results"]:
            rows.append({"round": int(rnd[1:]), "lean_model": lean == "lean1", **row})
    rec(
        "throughput_h100_lean_vs_full_model",
        "MJX env steps/s on one H100, the lean device model against the full one",
        rows,
        machine=H100,
        sha="2b106cf",
        sha_how=MEASURED_BEFORE,
        versions={"python": "3.12.3", "jax": "0.11.2", "mujoco-mjx": "3.17.0"},
        recovered_versions=("mujoco-mjx",),
        command=d["command"],
        engine="mjx",
        notes=d["machine"],
    )
    bench_file(
        "reacher_plain_h100",
        "throughput_h100_reacher_plain_step",
        "Reacher-v0 (plain mjx.step, planar fingertip) env steps/s on one H100",
        H100,
        "290f6ff",
        "python3 -m jaxenvs bench --tasks Reacher-v0 --batches 65536 262144 --modes full "
        "--repeats 3",
        {"mujoco-mjx": "3.17.0"},
        sha_how=MEASURED_BEFORE,
        engine="mjx",
    )
    bench_file(
        "walker_solver_h100",
        "walker_solver_variants_h100",
        "HexapodWalk-v0 env steps/s and stability under other solver settings, one H100",
        H100,
        "290f6ff",
        "python3 benchmarks/studies/walker_solver.py --variants base sub3 elliptic newton "
        "newton2 sub3_newton --batches 65536 --steps 20 --repeats 3 --json walker_solver.json",
        {"mujoco-mjx": "3.17.0"},
        sha_how=MEASURED_BEFORE,
        command_how="NOTES.md's text",
        engine="mjx",
    )
    d = old("scaling_h200x2")
    rec(
        "scaling_h200x2_reacher_walker",
        "Env steps/s and PPO on 1 and 2 H200s (strong and weak scaling)",
        d["results"],
        machine=H200X2,
        sha="b102c50",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.11.2"},
        command="python3 benchmarks/scaling.py --tasks Reacher-v0 HexapodWalk-v0 --devices 1 2 "
        "--envs 16384 --ppo-envs 8192 --steps 50 --repeats 3 --ppo-updates 2 --json scaling.json",
        command_how="RESULTS.md's text",
        date="2026-11-23",
        date_how="RESULTS.md's text",
        machine_how="the file's machine string: " + d["machine"],
        engine="mjx",
        extra={"args": d["args"]},
    )
    h200 = [
        ("CartPole-v0", 4096, 17.7e6, 29.5e6, 31.2e6, 3.6, 19),
        ("CartPole-v0", 16384, 50.5e6, 79.6e6, 83.2e6, 3.4, 75),
        ("CartPole-v0", 65536, 107.9e6, 145.1e6, 151.6e6, 3.8, 301),
        ("CartPole-v0", 262144, 143.8e6, 159.6e6, 162.3e6, 3.8, 1204),
        ("Reacher-v0", 4096, 15.9e6, 21.4e6, 22.3e6, 7.4, 25),
        ("Reacher-v0", 16384, 41.9e6, 53.8e6, 55.8e6, 6.4, 102),
        ("Reacher-v0", 65536, 78.6e6, 96.3e6, 91.4e6, 6.2, 406),
        ("Reacher-v0", 262144, 100.0e6, 115.0e6, 81.4e6, 6.6, 1642),
    ]
    rec(
        "throughput_h200_modes",
        "MJX env steps/s on one H200: full step, functional step, raw physics",
        [
            {
                "task": t,
                "num_envs": n,
                "full": f,
                "functional": fn,
                "physics": ph,
                "first_call_s_full": fc,
                "xla_program_mib": mib,
            }
            for t, n, f, fn, ph, fc, mib in h200
        ],
        machine=dict(H200, gpu="NVIDIA H200 (143,771 MiB, driver 580.159.04)"),
        sha="95f9559",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.11.2"},
        recovered_versions=("jax",),
        command="CUDA_VISIBLE_DEVICES=0 python3 -m jaxenvs bench --tasks CartPole-v0 "
        "--batches 4096 16384 65536 262144 --modes full functional physics --repeats 5 "
        "--json gpu.json   # and the same with --tasks Reacher-v0",
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures, rounded there (gpu.json was not committed)",
        engine="mjx",
        notes="the first GPU of a 2-GPU H200 host; an older tree (before the lean model and "
        "the sparse mass matrix)",
    )
    soak = [
        ("CartPole-v0", 19.1, 0, 4892183, 3.96, 3320, 3321),
        ("CartpoleStayUp-v0", 11.3, 0, 5036257, 3.77, 3347, 3347),
        ("CartpoleBalance-v0", 19.1, 30472661, 205379, 13.7, 3503, 3503),
        ("CartpoleSwingup-v0", 21.1, 30472661, 203771, 7.15, 3528, 3528),
        ("Reacher-v0", 12.7, 30472661, 2031616, 57.2, 3605, 3605),
        ("HexapodWalk-v0", 199.9, 30472661, 1252013, 22.3, 3669, 3669),
        ("HexapodOneLeg-v0", 20.9, 30472661, 1015808, 7.29, 3684, 3684),
    ]
    rec(
        "soak_h100_all_tasks",
        "1e8 env steps per task under random and extreme actions, one H100",
        [
            {
                "task": t,
                "env_steps": 101580800,
                "wall_s": w,
                "nonfinite_obs": 0,
                "nonfinite_reward": 0,
                "diverged": 0,
                "nan_inf_actions": a,
                "episodes": e,
                "max_abs_obs": mo,
                "rss_first_block_mib": r0,
                "rss_last_mib": r1,
            }
            for t, w, a, e, mo, r0, r1 in soak
        ],
        machine=H100,
        sha="9623998",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.11.2"},
        recovered_versions=("jax",),
        command="python3 benchmarks/soak.py --steps 1e8 --seconds 240 --num-envs 16384 "
        "--block 200 --out soak_gpu.json",
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures (soak_gpu.json was not committed)",
        engine="mjx",
        notes="16,384 envs, 200-step blocks, 31 blocks per task; discrete tasks take no "
        "NaN/inf actions; host RSS of the Python process (the env state lives on the GPU)",
    )
    # --- PPO -----------------------------------------------------------------------------
    ppo_rows = [
        ("CartpoleStayUp-v0", None, "0-2 (vmapped)", ["1000", "1000", "1000"], 196608,
         [38.2], [59.7], None),
        ("CartpoleBalance-v0", ">= 950 within 2 min", "0, 1, 2", ["999.3", "999.1", "999.4"],
         524288, [23.7, 23.7, 24.8], [41.4, 40.7, 41.8], "yes"),
        ("CartpoleSwingup-v0", ">= 800", "0, 1, 2", ["867.3", "881.3", "870.8"], 6291456,
         [92.7, 92.6, 91.4], [111.6, 113.0, 111.9], "yes"),
        ("Reacher-v0", ">= -3.75", "0, 1, 2", ["-2.82", "-2.43", "-2.25"], 1280000,
         [60.2, 60.1, 30.7], [88.2, 85.8, 40.9], "yes (seed 2 with a warm compile cache)"),
    ]  # fmt: skip
    rows = [
        {
            "env_id": i,
            "target": tgt,
            "seeds": s,
            "eval_return": ev,
            "env_steps": n,
            "train_wall_s": tw,
            "process_wall_s": pw,
            "met": met,
        }
        for i, tgt, s, ev, n, tw, pw, met in ppo_rows
    ]
    rec(
        "ppo_cpu2_cartpoles_reacher",
        "PPO on the cartpoles and the reacher with the shipped configs, 2 pinned cores",
        rows,
        machine=PINNED2,
        sha="58e77f4",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.11.2", "mujoco": "4.0.0", "mujoco-mjx": "3.17.0"},
        recovered_versions=("jax", "mujoco", "mujoco-mjx"),
        command="jaxenvs train ID --algo ppo --no-video --quiet [--seed S | --num-seeds 3]",
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures (the run directories were not committed)",
        engine="mjx",
        notes="up to 8 such 2-core jobs side by side on the host; train = summary.json "
        "wall_seconds, process = the whole command; eval = mean of 20 greedy episodes",
    )
    rec(
        "ppo_cpu2_oneleg",
        "PPO on HexapodOneLeg-v0 with the shipped config, 2 pinned cores",
        [
            {
                "env_id": "HexapodOneLeg-v0",
                "target": "final foot-tip error <= 1 cm",
                "seeds": "0, 1, 2",
                "final_tip_error_cm_mean": [0.94, 1.04, 0.98],
                "final_tip_error_cm_median": [0.82, 0.82, 0.83],
                "env_steps": 5120000,
                "train_wall_s": [198.3, 202.2, 201.5],
                "process_wall_s": [205.6, 208.2, 208.5],
                "met": "2 of 3 seeds; seed 1 misses by 0.4 mm",
            }
        ],
        machine=PINNED2,
        sha="f1e5159",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.11.2", "mujoco": "4.0.0", "mujoco-mjx": "3.17.0"},
        recovered_versions=("jax", "mujoco", "mujoco-mjx"),
        command="jaxenvs train HexapodOneLeg-v0 --algo ppo --no-video --quiet --seed S; "
        "python benchmarks/studies/final_metric.py RUN --metric distance --episodes 100",
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures (the run directories were not committed)",
        engine="mjx",
    )
    rec(
        "ppo_cartpole_cpu2_cold_warm",
        "CartPole-v0 PPO (shipped config) cold then warm, traced programs stored, 2 cores",
        [
            {"round": i + 1, "cache": c, "train_wall_s": t, "process_wall_s": p, "eval": 500}
            for i, (c, t, p) in enumerate(
                [("cold", 33.8, 39.2), ("cold", 27.7, 32.6), ("cold", 28.8, 33.5)]
            )
        ]
        + [
            {"round": i + 1, "cache": c, "train_wall_s": t, "process_wall_s": p, "eval": 500}
            for i, (c, t, p) in enumerate(
                [("warm", 4.7, 9.2), ("warm", 3.4, 7.1), ("warm", 3.9, 8.7)]
            )
        ],
        machine=dict(DEV2, load="idle"),
        sha="2b106cf",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.10.2", "mujoco": "4.0.0"},
        recovered_versions=("jax", "mujoco"),
        command="rm -rf $JAXENVS_CACHE_DIR; jaxenvs train CartPole-v0 --algo ppo --no-video "
        "--quiet (cold), then the same again (warm); 3 rounds",
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures (the run directories were not committed)",
        engine="mjx",
        notes="131,072 env steps, the lean device model; target >= 475, <= 30 s cold, <= 10 s warm",
    )
    d = old("walker_seeds")
    process = {("walk-v2-s0"): 304, "walk-v2-s1": 328, "walk-v2-s2": 282}
    for row in d:
        if row["run"] in process:
            row["process_wall_s"] = process[row["run"]]
    d.insert(
        2,
        {
            "seed": 1,
            "run": "walk-v1-s1 (not kept)",
            "train_seconds": 412.3,
            "gpu": "NVIDIA H200",
            "env_steps": 117440512,
            "config_diff": {"agent.total_steps": 117440512, "agent.ent_coef": 0.01},
            "speed_m_per_s": 0.859,
            "fell_fraction": 0.039,
            "targets_reached": 0.977,
            "randomized": {"speed_m_per_s": 0.851, "fell_fraction": 0.047,
                           "targets_reached": 0.965},
            "mujoco_c": {"speed_m_per_s": 0.847, "fell_fraction": 0.066,
                         "targets_reached": 0.98},
            "mujoco_c_randomized": {"speed_m_per_s": 0.833, "fell_fraction": 0.211,
                                    "targets_reached": 0.887},
            "recovered": "RESULTS.md's figures from the run's evaluation logs "
            "(its run directory was not kept)",
        },
    )  # fmt: skip
    rec(
        "ppo_walker_seeds_h200",
        "HexapodWalk-v0 PPO per seed: train wall, greedy speed, falls, targets reached",
        d,
        machine=dict(
            H200,
            description="one NVIDIA H200 (training, MJX eval); the C eval on the same host's "
            "16 CPU cores or, for seeds 1 and 2 of the shipped config, a 2-core CPU machine",
        ),
        sha="835c9fe",
        sha_how="the commit that last changed the file (2936517 added it)",
        versions={"jax": "0.11 (CUDA)", "mujoco-mjx": "3.17.0"},
        recovered_versions=("jax", "mujoco-mjx"),
        command="jaxenvs train HexapodWalk-v0 --algo ppo --no-video [--seed S]; "
        "python benchmarks/walker_seeds.py eval RUN [--physics c]; "
        "python benchmarks/walker_seeds.py table RUN... --json benchmarks/walker_seeds.json",
        command_how="RESULTS.md's text",
        rows_how="the file's records; process_wall_s and the v1 seed-1 record from "
        "RESULTS.md's figures",
        engine="mjx (training); per field: mujoco_c* under C",
    )
    rec(
        "tabular_cartpole_cold_cpu2",
        "Tabular Q-learning and SARSA on CartPole-v0, cold whole command, idle 2 cores",
        [
            {
                "agent": "qlearning",
                "eval_return": 240.2,
                "eval_std": 107.1,
                "process_wall_s": 35.4,
                "train_wall_s": 29.6,
            },
            {
                "agent": "sarsa",
                "eval_return": 216.1,
                "eval_std": 71.9,
                "process_wall_s": 33.2,
                "train_wall_s": 26.7,
            },
        ],
        machine=dict(DEV2, load="idle"),
        sha="2503c9d",
        sha_how=MEASURED_BEFORE,
        versions={"jax": "0.10.2"},
        recovered_versions=("jax",),
        command="jaxenvs train CartPole-v0 --algo {qlearning,sarsa} --no-compile-cache "
        "--no-video --quiet",
        command_how="RESULTS.md's text",
        rows_how="RESULTS.md's figures (the run directories were not committed)",
        engine="mjx",
        notes="target: eval >= 195 within 60 s wall, compile included",
    )


if __name__ == "__main__":
    main()
