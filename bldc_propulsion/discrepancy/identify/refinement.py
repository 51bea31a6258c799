"""The rule that applies the identification to a round's proposal (the network kind's: its scores
are residual corrections, which cannot see a changed response).

Heating is identified first (a hotter winding also brakes and drives a little less, which the
step responses would take for a slower rotor, while no dynamic effect makes the steady speed
depend on the thermal state); then, when the dynamic family or the start level is in question,
the response is identified on both sets (once per run: ``Identification.response``) and the one
``which_dynamic`` finds changed is named at its identified parameters.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from ... import contract as c
from ...recordings import Signals
from ..base import Progress, Proposal, Refined
from ..results import Evidence
from .dynamics import DYNAMIC_EFFECTS, RESPONSE_EFFECTS, StepDynamics, judged, step_dynamics, which_dynamic
from .heating import HEATING_TAU_S, identify_heating
from .recording_fit import Dynamics, identify_dynamics, identify_start_level
from .static_shape import SHIFT_MIN_RISE, start_level_within

#: Measured residual RMSE >= this x the reference's, with no residual feature significant: the
#: response (dynamics, start level) is identified directly all the same.
GAP_RATIO = 1.5


@dataclass
class Response:
    """The rotor's response identified on both sets: the fits of the whole recordings and what
    their command steps and holds show changed."""

    measured: Dynamics
    reference: Dynamics
    steps: StepDynamics


@dataclass
class Identification:
    """One run's identification: the recordings it compares, the levels a residual feature counts
    as significant at (``Options.alpha``, ``Options.min_effect``), and the response, identified the
    first time a round needs it and the same for every later round."""

    measured: Sequence[Signals]
    reference: Sequence[Signals]
    alpha: float
    min_effect: float
    response: Response | None = None
    #: the latest round's verdict on the response (which changed or None, why, the figures, the
    #: members it could judge): a later round that does not identify again keeps it
    verdict: tuple[str | None, str, dict[str, object], frozenset[str]] | None = None


def refine(proposal: Proposal, run: Identification, rmse: tuple[float, float], progress: Progress) -> Refined:
    """Apply the identification to one round (``proposal.evidence`` is changed in place; ``rmse``:
    the current model's residual RMSE on the measured and the reference data, rad/s). Needs
    reference recordings (else nothing changes):

    - motor_heating, when nothing or one of RESPONSE_EFFECTS is proposed: named when
      ``identify_heating`` says its response to the thermal state changed, not new when the
      measured data stay below HEATING_MIN_STATE (they cannot show heating);
    - the dynamic family and the start level, when the scores propose one of them
      (RESPONSE_EFFECTS), a dynamic candidate is significant on the measured data alone or the
      measured residual RMSE is GAP_RATIO x the reference's with nothing new: the one
      ``which_dynamic`` finds changed is named (at the identified parameters); when none
      changed, none of them is new (the start level included: with esc_deadband offered, the
      identification always judges it, from held levels or the fitted start level). The scores'
      start-level proposal is not taken as it comes: a slower rotor and a heating winding leave
      residual structure the start level's feature fits too, and only the identification tells
      them apart."""
    ev = proposal.evidence
    out = Refined(proposal.best)
    if not run.reference:
        return out
    if "motor_heating" in ev and (out.best is None or out.best in RESPONSE_EFFECTS) \
            and _heating_changed(ev["motor_heating"], run, progress):
        out.best, out.params = "motor_heating", {"tau_s": HEATING_TAU_S}
    elif out.best == "motor_heating" and not _heating_changed(ev["motor_heating"], run, progress) \
            and ev["motor_heating"].verdict.startswith("not new"):
        # the scores' own proposal, from data that never warm the winding: their thermal state's
        # slow feature fits what a slower spin-down leaves too (a foreign coasting ESC's measured
        # data, hottest state 0.06, took heating first and the spin-down was never tried on a
        # model that could still learn it); the response is asked instead
        out.best = None
    if (out.best is not None and out.best not in RESPONSE_EFFECTS) \
            or not _response_in_question(ev, out.best, run, rmse):
        if run.verdict is not None:  # identified in an earlier round: that verdict still holds
            _others_not_new(ev, *run.verdict)
            if out.best is None:
                _retry_identified(ev, proposal.added, run, out)
        return out
    # (judged on the measured data alone: which dynamic effect changed is decided by identifying
    # the response directly, not by the pooled residual correction) the measured residual has
    # significant dynamic structure, or is far larger than the reference's with no residual
    # feature to explain it (a changed static map, as a start level, re-weights into the null
    # columns); whether anything is NEW is decided by comparing the identified response with
    # the reference's
    if out.best is None:
        dyn_sig = [k for k in ev if k in DYNAMIC_EFFECTS and ev[k].measured_alone.p_value < run.alpha]
        out.best = max(dyn_sig, key=lambda k: ev[k].measured_alone.fraction, default=None)
    gap_txt = (f"({out.best}'s feature removes {100 * ev[out.best].measured_alone.fraction:.0f} % of it, "
               f"p = {ev[out.best].measured_alone.p_value:.2g})" if out.best is not None else
               f"(its RMSE is {rmse[0]:.1f} rad/s vs {rmse[1]:.1f} rad/s on the reference)")
    resp = _response(run, "esc_deadband" in ev, progress)
    choice, why = which_dynamic(resp.measured, resp.reference, steps=resp.steps,
                                exclude=[*proposal.added, *(set(c.EFFECTS) - set(ev))])
    info: dict[str, object] = {"measured": resp.measured.as_dict(), "reference": resp.reference.as_dict(),
            "step_responses": resp.steps.as_dict(), "changed": choice, "because": why}
    progress(f"  identified dynamics: {why}")
    run.verdict = (choice, why, info, judged(resp.steps))
    if choice is None:
        out.best = _none_changed(ev, info)
    elif choice not in proposal.added and choice in ev:
        ev[choice].override("new", f"{choice}: {why}; the model's residual on the measured data "
                                   f"follows the command {gap_txt}")
        out.best = choice
    _others_not_new(ev, *run.verdict)
    if out.best is not None and choice == out.best:
        out.params, out.reference_params = _identified_params(choice, resp)
    if out.best is not None:
        ev[out.best].dynamics = info
    return out


def _retry_identified(ev: dict[str, Evidence], added: Sequence[str], run: Identification, out: Refined) -> None:
    """Nothing is proposed, and the response identified in an earlier round changed in an effect
    the model still lacks: it is tried again, at its identified parameters. The held-out test
    that rejected it judged the model as it then was; what was added since (a lag that every
    bench's rotor has) may be what the change needed to show (a dead time before a lag the model
    lacked may gain little on held-out data, and the same dead time after the lag much more).
    Tried once per round: a round that adds nothing ends the run."""
    assert run.verdict is not None and run.response is not None
    choice, why, info, _ = run.verdict
    if choice is None or choice in added or choice not in ev:
        return
    ev[choice].override("new", f"{choice}: {why} (identified in an earlier round, tried again on the model "
                               f"as it now is)")
    ev[choice].dynamics = info
    out.best = choice
    out.params, out.reference_params = _identified_params(choice, run.response)


def _heating_changed(e: Evidence, run: Identification, progress: Progress) -> bool:
    """Whether the speed's response to the same thermal state changed (``e`` gets the figures,
    and the verdict new when it did). The feature (driven by the command) is the same on both
    sets, so the pooled residual score cannot see it; identified on the speed directly, the
    measured and the reference sets fitted together."""
    heat = identify_heating(run.measured, run.reference)
    e.heating = heat.as_dict()
    progress(f"  identified heating: {heat.describe()}")
    if heat.changed:
        e.override("new", f"motor_heating: {heat.describe()}")
    elif heat.too_cool:
        # the measured data never warm the winding enough for its heating to move the speed: a
        # thermal state's slow feature that helps them helps as any slow input would (a rotor
        # coasting below a start level, a sagging pack), so the scores do not make it new
        e.override("not new (the measured data do not warm the winding)",
                   f"motor_heating: not new: {heat.describe()}")
    return heat.changed


def _response_in_question(ev: dict[str, Evidence], best: str | None, run: Identification,
                          rmse: tuple[float, float]) -> bool:
    """The scores propose one of RESPONSE_EFFECTS, one of them will be tried all the same (new or
    structural on the measured data, or removing ``min_effect`` of their residual: the workflow's
    ``proposals``; its scores' parameters are a residual correction's, not the response's), a
    dynamic candidate is significant on the measured data alone, or nothing is proposed and the
    measured residual is GAP_RATIO x the reference's."""
    return (best in RESPONSE_EFFECTS
            or any(ev[k].proposed(run.min_effect) for k in ev if k in RESPONSE_EFFECTS)
            or any(ev[k].measured_alone.p_value < run.alpha and ev[k].measured_alone.fraction >= run.min_effect
                   for k in ev if k in DYNAMIC_EFFECTS)
            or (best is None and rmse[0] >= GAP_RATIO * rmse[1]))


def _response(run: Identification, start_level: bool, progress: Progress) -> Response:
    """The response on both sets, identified the first time a round asks (with the ESC start level
    when ``start_level``: esc_deadband is offered). Lag, dead time and spin-down all change the
    response to a command change, and a residual explained by one is partly explained by the
    others: which one CHANGED is decided by identifying the response itself on both sets."""
    if run.response is None:
        progress("  a dynamic effect or the ESC start level is in question: identifying dead time, "
                 "start level and spin-up/spin-down time constants on the measured and the reference "
                 "recordings")
        meas, ref = identify_dynamics(run.measured), identify_dynamics(run.reference)
        if start_level:
            for dy, sigs in ((meas, run.measured), (ref, run.reference)):
                dy.start_level = identify_start_level(sigs, dy)
        steps = step_dynamics(run.measured, run.reference, start_level=meas.start_level if start_level else None)
        run.response = Response(meas, ref, steps)
    return run.response


def _others_not_new(ev: dict[str, Evidence], choice: str | None, why: str, info: dict[str, object],
                    shown: frozenset[str]) -> None:
    """The identified response decides which of RESPONSE_EFFECTS changed (``choice``): every other
    one the scores did not find structural is not new, whatever its scores (their features fit
    what did change: a rotor left to coast to rest below a raised start level is a slower
    spin-down to them). It may still be added where the model lacks it, as structural
    (``workflow.added_as``). Where none changed (``choice`` None), only the members whose
    quantity the steps or holds could judge (``shown``) are not new: of a member with too few
    steps nothing is known (a non-braking ESC's spin-down, with few falling steps), so the
    holdout may still find it new."""
    verdict = f"not new (identified: {choice} changed)" if choice else "not new (identified dynamics unchanged)"
    for k in RESPONSE_EFFECTS:
        if k != choice and k in ev and ev[k].verdict in ("new", "not significant") \
                and (choice is not None or k in shown):
            ev[k].override(verdict, f"{k}: not new: the identified response says {why}, which {k}'s "
                                    "feature also fits")
            ev[k].dynamics = info


def _none_changed(ev: dict[str, Evidence], info: dict[str, object]) -> str | None:
    """The response to the command did not change: the residual's dynamic structure is the model's
    own (it is there on the reference too), so none of RESPONSE_EFFECTS is new. The proposal is
    then the other candidate new on the measured data that removes the most, if any."""
    for k in RESPONSE_EFFECTS:
        if k in ev and ev[k].verdict in ("new", "structural"):
            ev[k].verdict = "not new (identified dynamics unchanged)"
            ev[k].dynamics = info
    others = [k for k in ev if k not in RESPONSE_EFFECTS and ev[k].verdict == "new"]
    return max(others, key=lambda k: ev[k].measured.fraction, default=None)


def _identified_params(choice: str, resp: Response) -> tuple[dict[str, float] | None, dict[str, float] | None]:
    """The parameters the identification fixed for ``choice``, on the measured data and on the
    reference itself (None: the kind fits them)."""
    m, r, steps = resp.measured, resp.reference, resp.steps
    if choice == "rotor_lag":
        return {"tau_s": max(m.tau_up_s, 0.02)}, None
    if choice == "spin_down_asymmetry":
        return {"tau_up_s": max(m.tau_up_s, 0.02), "tau_down_s": max(m.tau_down_s, 0.04)}, None
    if choice == "input_delay":
        # the model already has the reference's own dead time: the delay added is the change, and
        # the reference has none of it
        change = steps.dead_time.change if steps.dead_time is not None else m.delay_s - r.delay_s
        return {"delay_s": max(change, 0.01)}, {"delay_s": 0.0}
    if choice == "esc_deadband":
        # never at or below a held level where the measured rotor got no drive (the fits read
        # the map's compression and how late the rotor leaves rest, which a coarse grid or the
        # dynamics can put below such a level: a foreign bench's rotor stayed at rest at 0.0544
        # and the fitted 0.052 left the network an input that could not say so)
        bounds = steps.start_level_bounds
        shift = steps.start_level_shift
        # below the start level the rotor gets no drive: it slows as the measured data's falls do
        # (an ESC that does not brake leaves it to coast to rest for seconds)
        coast = {"coast_tau_s": m.tau_down_s}
        if shift is not None and shift.changed:
            # the settled holds' levels: read on a finer grid reaching further than the
            # whole-recording fit's, and not moved by the dynamics
            start, ref_level = shift.measured, shift.reference
        elif shift is not None:
            # the settled map did not move (the holds show no drive below a level all the same):
            # the measured map starts where the reference's does
            start, ref_level = shift.reference, shift.reference
        else:
            start, ref_level = m.start_level, r.start_level
        threshold = start_level_within(start, bounds)
        meas: dict[str, float] = {"threshold": threshold, **coast}
        if threshold > start + SHIFT_MIN_RISE:
            # no drive where the settled map says the ESC would drive: it gates a map that starts
            # lower (``effect_features``: a map moved to start at the gate would read every
            # level above it as less drive than the rotor got)
            meas["map_level"] = start
        return meas, {"threshold": ref_level}
    return None, None
