"""``jaxenvs list``: the registered ids with their spaces."""

from __future__ import annotations

import argparse

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
    rows = [("id", "obs", "actions", "steps", "description")]
    for env_id in ids:
        env = jaxenvs.make(env_id)
        actions = f"Discrete({env.action_size})" if env.discrete else f"Box({env.action_size})"
        rows.append(
            (
                env_id,
                str(env.observation_size),
                actions,
                str(env.episode_length),
                spec(env_id).description,
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    for r in rows:
        print("  ".join(c.ljust(w) for c, w in zip(r[:4], widths, strict=True)) + "  " + r[4])
    return 0
