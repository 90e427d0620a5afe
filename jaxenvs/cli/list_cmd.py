"""``jaxenvs list``: the registered ids with their spaces."""

from __future__ import annotations

import argparse

from jaxenvs.physics.figures import figures_for

HELP = "list registered env ids with observation and action sizes"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--ids", action="store_true", help="print the ids only")


def run(args: argparse.Namespace) -> int:
    import jaxenvs
    from jaxenvs.registry import spec

    ids = jaxenvs.list_envs()
    if args.ids:
        print("\n".join(ids))
        return 0
    rows = [("id", "obs", "actions", "steps", "cpu physics", "description")]
    for env_id in ids:
        env = jaxenvs.make(env_id, physics="mjx")
        assert isinstance(env, jaxenvs.Env)
        actions = f"Discrete({env.action_size})" if env.discrete else f"Box({env.action_size})"
        rows.append(
            (
                env_id,
                str(env.observation_size),
                actions,
                str(env.episode_length),
                figures_for(type(env)).cpu_physics,
                spec(env_id).description,
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(5)]
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r[:5], widths, strict=True)) + "  " + r[5])
    print(
        "\ncpu physics: the engine physics='auto' (the default) steps on a CPU; "
        "MJX on a GPU or TPU (--physics to choose)"
    )
    return 0
