"""The strategies a run can use, one entry each: name, options, how it is built, its rerunnable stages.

A strategy is one module in ``strategies/`` (its ask-tell class, :mod:`.base`; its options dataclass with
:func:`.options.setting` fields; a ``build(context, *options)`` function) and one :func:`register` line here.
Everything else follows from the entry: the run's config keys, TOML file and flags (``flows/config.py``), the
``--strategy`` choices, the driver that runs it as Prefect stages (``tasks/driver.py``, ``flows/drive.py``),
the manifest's stages, ``rerun``'s stages and the summary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace

from . import coordinate_search, hybrid, paper, polish
from .base import Context
from .hybrid import CAP_FACTOR, HybridOptions
from .options import from_settings
from .paper import PaperLoop, PaperOptions
from .polish import Polish, PolishOptions
from .sequence import Sequence

__all__ = ["StrategySpec", "REGISTRY", "register", "get", "names", "option_classes"]


@dataclass(frozen=True)
class StrategySpec:
    """One strategy of the registry.

    name : its ``--strategy`` name; help : one line for ``--help``;
    options : the dataclasses of its settings (:mod:`.options`), built from the run's config in this order;
    build : ``build(context, *options) -> strategy`` (:class:`.base.Context`: the run's problem);
    stages : the stages of its iterations in the run folder (the manifest lists them);
    rerunnable : the stages ``rerun`` recomputes (the intervals are every strategy's);
    round_word : the name of an iteration in the log and the Prefect UI (``cycle-2``);
    modes : ``modes(*options) -> bool``: its FE runs give the lowest modes (the run resolves how many);
    budget : ``budget(config) -> (FE runs, iterations)`` at most, for the disk-space check.
    """

    name: str
    help: str
    options: tuple
    build: Callable
    stages: tuple = ("fe",)
    rerunnable: tuple = ()
    round_word: str = "iteration"
    modes: Callable = field(default=lambda *options: False)
    budget: Callable = field(default=lambda config: (config.max_fe_evaluations, config.max_iterations))

    def settings(self, config, **fixed) -> tuple:
        """The strategy's options from a config (:func:`.options.from_settings`)."""
        return tuple(from_settings(cls, config) for cls in self.options)

    def make(self, context: Context, config):
        return self.build(context, *self.settings(config))


REGISTRY: dict[str, StrategySpec] = {}


def register(spec: StrategySpec) -> StrategySpec:
    REGISTRY[spec.name] = spec
    return spec


def get(name: str) -> StrategySpec:
    return REGISTRY[name]


def names() -> tuple[str, ...]:
    return tuple(REGISTRY)


def option_classes() -> list[type]:
    """Every registered options dataclass, once, in registration order."""
    out = []
    for spec in REGISTRY.values():
        out += [cls for cls in spec.options if cls not in out]
    return out


# -- how each strategy is built from a run's problem ---------------------------------------------------------
def _hybrid(ctx: Context, options: HybridOptions):
    options = replace(options, cap=CAP_FACTOR * options.max_cost, jacobian_cost=ctx.jacobian_cost,
                      weigh_early=options.weigh_early or ctx.large)
    return hybrid.Hybrid(ctx.nominal, ctx.residual, *ctx.solver_box, options, ctx.screen_model,
                         ctx.names, ctx.memo)


def _paper(ctx: Context, options: PaperOptions, conventional: bool = False) -> PaperLoop:
    options = replace(options, conventional=conventional)
    layout = ctx.modal_layout() if options.modes else None
    return PaperLoop(options, ctx.residual, ctx.lower, ctx.upper, ctx.solver_box, layout, ctx.names, ctx.memo)


def _adaptive(ctx: Context, options: PaperOptions, polishing: PolishOptions):
    """The paper's loop, then (``polish``) the polish from its best FE run, on the budget left to it."""
    if not polishing.enabled:
        return _paper(ctx, options)
    loop = _paper(ctx, replace(options, max_fe=options.max_fe - polishing.max_evaluations))

    def then(loop: PaperLoop) -> Polish:
        i = loop.best_index()
        return Polish(loop.X[i], loop.Z[i], ctx.residual, *ctx.solver_box, polishing, loop.iteration,
                      options.threshold, loop.ids[i])

    return Sequence(loop, then, titles=("MRGP loop", "polish"))


register(StrategySpec(
    "hybrid", "Gauss-Newton from the nominal model, global with the MRGP emulator when the residual is not noise "
              "(the default)", (HybridOptions,), _hybrid, hybrid.STAGES, hybrid.RERUNNABLE, round_word="cycle"))
register(StrategySpec(
    "adaptive", "the paper's MRGP loop, then the polish (with --no-polish exactly the paper's procedure)",
    (PaperOptions, PolishOptions), _adaptive, (*paper.STAGES, polish.STAGE), paper.RERUNNABLE,
    modes=lambda options, polishing: options.modes))
register(StrategySpec(
    "conventional", "the paper's 300-sample baseline (Section 3.4): uniform FE runs, one MRGP, its best prediction",
    (PaperOptions,), lambda ctx, options: _paper(ctx, options, conventional=True), paper.STAGES, paper.RERUNNABLE,
    budget=lambda config: (config.conventional_samples + 1, 2)))
register(StrategySpec(
    "coordinate", "a coordinate search (the toy of docs/guide/architecture.md): one step along each axis per round",
    (coordinate_search.CoordinateOptions,), coordinate_search.build, coordinate_search.STAGES, coordinate_search.STAGES))
