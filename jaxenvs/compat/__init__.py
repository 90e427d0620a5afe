"""Adapters that put jaxenvs tasks behind other libraries' env interfaces.

* :mod:`jaxenvs.compat.gymnasium`: every id as ``gymnasium.make("jaxenvs/<id>")`` and
  ``gymnasium.make_vec(...)`` (registered by ``import jaxenvs``; docs/gymnasium.md).
* :mod:`jaxenvs.compat.gymnax`: every id as a gymnax ``Environment`` for gymnax-API JAX
  training code, PureJaxRL-style loops and rejax (the ``gymnax`` extra; docs/gymnax.md).
* :mod:`jaxenvs.compat.brax`: a task as a Brax ``Env`` for Brax's agents (the ``brax``
  extra).

The optional ones are imported by name only, so a missing extra costs nothing until used.
"""
