"""Whole-command times of the README's main job, cold and warm, beside SB3 on CartPole-v1.

Each round runs, interleaved so that the shared machine's load falls on all of them alike:
``jaxenvs train CartPole-v0 --algo ppo`` (video included, as the README runs it) against a
fresh compile cache (cold), the same again against that cache (warm), and
Stable-Baselines3's PPO training Gymnasium's CartPole-v1 in a process of its own until a
20-episode deterministic evaluation (checked every ``--sb3-check-every`` steps, inside the
timed process) returns 500. Every time is the whole process's, from start to exit. The C
engine without video (cold, warm) closes each round. Every process runs as a user's shell
starts it: without ``PYTHONDONTWRITEBYTECODE`` (which some containers set), so that Python
keeps the modules it compiles; each cold run starts without the jaxenvs package's bytecode
caches, as a fresh clone's first run does, and the warm run finds what the cold one wrote.
Rows: one per process; the record's ``extra`` holds the medians over rounds and the ratios
ours / SB3. ``--xla-defaults`` adds, after each of our commands, the same command with
jaxenvs' XLA options emptied (``jaxenvs.core.xla.COMPILER_OPTIONS`` and ``ONCE_OPTIONS``
set to ``{}``: XLA's own defaults), cold and warm (rows ``<which>_xla_defaults``);
``--optimised-init`` the same with only ``ONCE_OPTIONS`` emptied (the run's init compiled
with LLVM's optimisations, as before :func:`jaxenvs.core.xla.jit_once`; rows
``<which>_optimised_init``). ``--sb3-defaults`` adds, after SB3's row, SB3's PPO with its
own default hyperparameters (one env; row ``sb3_defaults``), timed the same way.

SB3's hyperparameters are RL Baselines3 Zoo's tuned ones for CartPole-v1 (8 envs,
n_steps 32, batch 256, 20 epochs, gamma 0.98, GAE lambda 0.8, linearly decayed learning
rate 1e-3 and clip 0.2), on the CPU; it needs ``pip install 'jaxenvs[bench-sb3]'``.

    python benchmarks/main_command.py --rounds 3 --json main_command_cpu2
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import results_io
from sb3_zoo import default_cartpole_ppo, zoo_cartpole_ppo

COMMANDS = (
    ("main", ["train", "CartPole-v0", "--algo", "ppo"]),
    ("c_no_video", ["train", "CartPole-v0", "--algo", "ppo", "--physics", "c", "--no-video"]),
)
SB3_COMMAND = "SB3 PPO on Gymnasium CartPole-v1 until a 20-episode greedy eval returns 500"
EVAL_EPISODES = 20
THRESHOLD = 500.0


#: the variants of our commands: a row suffix and what the command line sets in
#: jaxenvs.core.xla (imported as ``x``) before it runs (None: ``python -m jaxenvs``)
VARIANTS = {
    "": None,
    "_xla_defaults": "x.COMPILER_OPTIONS = {}; x.ONCE_OPTIONS = {}",
    "_optimised_init": "x.ONCE_OPTIONS = {}",
}


def _program(variant: str) -> list[str]:
    setting = VARIANTS[variant]
    if setting is None:
        return ["-m", "jaxenvs"]
    return [
        "-c",
        f"import sys, jaxenvs.core.xla as x; {setting}; "
        "from jaxenvs.cli import main; sys.exit(main(sys.argv[1:]))",
    ]


def _user_env(**extra: str) -> dict[str, str]:
    """This process's environment as a user's shell has it (no ``PYTHONDONTWRITEBYTECODE``),
    plus ``extra``."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    return {**env, **extra}


def _drop_bytecode() -> None:
    """Remove the jaxenvs package's ``__pycache__`` directories (a fresh clone has none)."""
    import jaxenvs

    for d in list(Path(jaxenvs.__file__).resolve().parent.rglob("__pycache__")):
        shutil.rmtree(d, ignore_errors=True)


def _run(args: list[str], out: Path, cache: str, variant: str = "") -> dict[str, Any]:
    env = _user_env(JAXENVS_CACHE_DIR=cache)
    start = time.perf_counter()
    program = _program(variant)
    subprocess.run(
        [sys.executable, *program, *args, "--out", str(out), "--quiet"],
        check=True,
        env=env,
        timeout=900,
    )
    wall = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text())
    return {
        "whole_command_s": round(wall, 2),
        "train_wall_s": summary.get("wall_seconds"),
        "physics": summary.get("physics"),
        "eval_mean_return": summary.get("eval_mean_return"),
        "video": (out / "video.mp4").exists(),
    }


def sb3_job(seed: int, max_steps: int, check_every: int, defaults: bool) -> dict[str, Any]:
    """SB3's PPO on CartPole-v1 until solved (this process's side of an SB3 row): the Zoo's
    hyperparameters, or SB3's own ``defaults``."""
    import gymnasium
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.evaluation import evaluate_policy

    class Solved(BaseCallback):
        def __init__(self) -> None:
            super().__init__()
            self.eval_env = gymnasium.make("CartPole-v1")
            self.result: dict[str, Any] = {"solved": False, "eval_mean_return": None}
            self.next_check = check_every

        def _on_step(self) -> bool:
            if self.num_timesteps < self.next_check:
                return True
            self.next_check += check_every
            mean, _ = evaluate_policy(
                self.model, self.eval_env, n_eval_episodes=EVAL_EPISODES, deterministic=True
            )
            self.result = {"solved": bool(mean >= THRESHOLD), "eval_mean_return": float(mean)}
            self.result["env_steps"] = self.num_timesteps
            return mean < THRESHOLD

    model = default_cartpole_ppo(seed) if defaults else zoo_cartpole_ppo(seed)
    callback = Solved()
    model.learn(total_timesteps=max_steps, callback=callback)
    return callback.result


def _run_sb3(seed: int, max_steps: int, check_every: int, defaults: bool) -> dict[str, Any]:
    script = Path(__file__).resolve()
    job = ["--sb3-job", str(seed), str(max_steps), str(check_every)]
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, str(script), *job, *(["--sb3-defaults"] if defaults else [])],
        check=True,
        capture_output=True,
        text=True,
        timeout=1800,
        env=_user_env(),
    )
    wall = time.perf_counter() - start
    result = json.loads(done.stdout.strip().splitlines()[-1])
    return {"whole_command_s": round(wall, 2), **result}


def _medians(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """Median whole-process seconds of each kind of row, and ours / SB3 (Zoo, and defaults
    where run)."""
    groups: dict[str, list[float]] = {}
    for r in rows:
        groups.setdefault(f"{r['which']}_{r['run']}", []).append(r["whole_command_s"])
    med = {k: round(statistics.median(v), 2) for k, v in groups.items()}
    ratios = {}
    for ref, suffix in (("sb3_0", "sb3"), ("sb3_defaults_0", "sb3_defaults")):
        if med.get(ref):
            ratios.update(
                {
                    f"{k}_over_{suffix}": round(v / med[ref], 3)
                    for k, v in med.items()
                    if not k.startswith("sb3")
                }
            )
    return {"median_whole_command_s": med, "ratios": ratios}


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--sb3-max-steps", type=int, default=300_000)
    parser.add_argument("--sb3-check-every", type=int, default=10_000)
    parser.add_argument("--sb3-job", nargs=3, type=int, help=argparse.SUPPRESS)
    parser.add_argument("--xla-defaults", action="store_true", help="also with XLA's defaults")
    parser.add_argument(
        "--optimised-init", action="store_true", help="also with the init compiled optimised"
    )
    parser.add_argument(
        "--sb3-defaults", action="store_true", help="also SB3 with its default hyperparameters"
    )
    parser.add_argument("--json", help=results_io.HELP)
    args = parser.parse_args()
    if args.sb3_job:
        print(json.dumps(sb3_job(*args.sb3_job, args.sb3_defaults)), flush=True)
        return
    rows, loads = [], [_load()]
    for k in range(args.rounds):
        for name, command in COMMANDS:
            variants = [""] + ["_xla_defaults"] * args.xla_defaults
            variants += ["_optimised_init"] * args.optimised_init
            for variant in variants:
                which = name + variant
                with tempfile.TemporaryDirectory() as tmp:
                    cache = str(Path(tmp) / "cache")
                    for i in range(2):
                        if i == 0:
                            _drop_bytecode()
                        row = _run(command, Path(tmp) / f"run{i}", cache, variant)
                        head = {"command": "jaxenvs " + " ".join(command), "which": which}
                        rows.append({**head, "run": i, **row, "round": k})
                        print(rows[-1], flush=True)
            if name != "main":
                continue
            for which in ("sb3", "sb3_defaults") if args.sb3_defaults else ("sb3",):
                defaults = which == "sb3_defaults"
                row = _run_sb3(k, args.sb3_max_steps, args.sb3_check_every, defaults)
                said = SB3_COMMAND + (", SB3's default hyperparameters" if defaults else "")
                rows.append({"command": said, "which": which, "run": 0, **row, "round": k})
                print(rows[-1], flush=True)
        loads.append(_load())
    extra = _medians(rows)
    print(json.dumps(extra), flush=True)
    if args.json:
        title = "The README's main command cold and warm, beside SB3 on CartPole-v1"
        notes = (
            f"{args.rounds} interleaved rounds on a shared 2-core machine; load average "
            f"(1/5/15 min) before and after each round: {'; '.join(loads)}. SB3: RL "
            "Baselines3 Zoo's CartPole-v1 PPO hyperparameters"
            + (" (sb3_defaults: SB3's own defaults, one env)" if args.sb3_defaults else "")
            + ", seed = round, greedy "
            f"20-episode eval every {args.sb3_check_every} steps inside the timed process. "
            "Every process without PYTHONDONTWRITEBYTECODE; each cold run without the "
            "package's bytecode caches."
        )
        rec = results_io.record(args.json, title, rows, notes=notes, extra=extra)
        results_io.write(args.json, rec)


if __name__ == "__main__":
    main()
