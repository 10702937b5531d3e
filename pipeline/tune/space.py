"""The search space of an observer's gains: every gain log-uniform in its ``GainSpec.search`` range; a gain with a
stability ``limit`` is searched as a fraction of that limit, so every sampled set satisfies the observer's
conditions (``ObserverSpec.check_gains``) by construction and no trial is spent on a set that is refused."""

from __future__ import annotations

from slamobs.pipeline.observers import ObserverSpec

#: Prefix of the parameter of a gain searched as a fraction of its limit.
FRACTION = "fraction_of_limit:"


def param_name(gain) -> str:
    return f"{FRACTION}{gain.name}" if gain.limit is not None else gain.name


def distributions(spec: ObserverSpec) -> dict:
    """Optuna distributions, one per gain, in the spec's order (limits may depend on gains before them)."""
    from optuna.distributions import FloatDistribution

    return {param_name(g): FloatDistribution(g.search[0], g.search[1], log=True) for g in spec.gains}


def gains_of(spec: ObserverSpec, params: dict[str, float]) -> dict[str, float]:
    """The gains a parameter set stands for (limits applied in the spec's order)."""
    gains: dict[str, float] = {}
    for g in spec.gains:
        value = float(params[param_name(g)])
        if g.limit is not None:
            # the limit of a gain depends only on the other gains: their values (defaults while not yet known)
            value *= g.limit({**{x.name: x.default for x in spec.gains}, **gains, **_plain(spec, params)})
        gains[g.name] = value
    return gains


def _plain(spec: ObserverSpec, params: dict[str, float]) -> dict[str, float]:
    return {g.name: float(params[g.name]) for g in spec.gains if g.limit is None}


def params_of(spec: ObserverSpec, gains: dict[str, float]) -> dict[str, float]:
    """The parameter set of ``gains`` (e.g. the defaults, enqueued as the first trial)."""
    out = {}
    for g in spec.gains:
        value = gains[g.name]
        out[param_name(g)] = value / g.limit(gains) if g.limit is not None else value
    return out


def in_range(spec: ObserverSpec, params: dict[str, float]) -> bool:
    return all(g.search[0] <= params[param_name(g)] <= g.search[1] for g in spec.gains)


def describe(spec: ObserverSpec) -> list[dict]:
    """The space as plain data (tune.json, and what a resumed tune must match)."""
    return [
        {
            "gain": g.name,
            "low": g.search[0],
            "high": g.search[1],
            "log": True,
            "of_limit": g.limit is not None,
            "default": g.default,
        }
        for g in spec.gains
    ]
