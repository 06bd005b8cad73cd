"""What a diagnosis says of itself: the lines of :meth:`~tak_thermo_ros.core.diagnose.values.Diagnosis.summary`.

A :class:`~tak_thermo_ros.core.diagnose.values.Diagnosis` prints from itself alone, as a fit's
result does (:mod:`tak_thermo_ros.core.fit.summary`): the residual per axis against the noise
floor (or against the noise model's held-out means), the Allan test of the residual, the
candidates tried with the share of the excess each removes, the model ladder, the verdict and its
statements. ``tak_calib diagnose`` prints these lines between its own (what was read, the noise
model's source, the record's temperature course).
"""

from __future__ import annotations

from tak_thermo_ros.units import amount, display_unit, in_driver_words


def axes_lines(diagnosis, unit: str) -> list[str]:
    """The residual per axis against the floor, one quantity per line (x y z)."""
    axes = diagnosis.axes
    ratios = ' '.join(f'{a.heldout_rms / a.noise_floor:.2f}x' for a in axes)
    lines = [f'  residual RMS x y z  {amount([a.rms for a in axes], unit)}']
    if diagnosis.averaging_time_s:
        means = f'{diagnosis.averaging_time_s:.3g} s means'
        return [*lines,
                f'  white floor         {amount([a.white_floor for a in axes], unit)}',
                f'  RMS of held-out {means}:',
                f'    the noise model   {amount([a.noise_floor for a in axes], unit)}',
                f'    measured          {amount([a.heldout_rms for a in axes], unit)}',
                f'  held-out / model    {ratios}']
    return [*lines,
            f'  noise floor         {amount([a.noise_floor for a in axes], unit)}',
            f'  held-out RMS        {amount([a.heldout_rms for a in axes], unit)}',
            f'  held-out / floor    {ratios}']


def allan_lines(diagnosis) -> list[str]:
    """The Allan test of the last rung's residual against the noise model (nothing without a model)."""
    if not diagnosis.allan:
        return []
    return diagnosis.allan[-1][1].summary_lines(' after the ladder' if len(diagnosis.allan) > 1 else '')


def search_lines(diagnosis, unit: str) -> list[str]:
    """The candidates tried (held-out RMS, share of the excess removed), those not tried, the model ladder."""
    shown_unit, scale = display_unit(unit)
    lines = []
    if diagnosis.candidates:
        lines.append(f'candidates, best first: held-out RMS x y z in {shown_unit}, share of the excess removed')
        for candidate in diagnosis.candidates:
            rms = ' '.join(f'{v * scale:9.4g}' for v in candidate.rms_after)
            lines.append(f'  {candidate.effect:<20} {rms}  {round(100.0 * candidate.explained):5d}%')
    for name, reason in diagnosis.skipped.items():
        lines.append(f'  {name:<20} not tried: {reason}')
    if len(diagnosis.ladder) > 1:
        lines.append(f'model ladder: held-out RMS x y z in {shown_unit}')
        for step in diagnosis.ladder:
            lines.append(f'  {step.label:<28} {" ".join(f"{v * scale:.4g}" for v in step.heldout_rms)}')
    return lines


def statement_lines(diagnosis, *, verbose: bool = False, driver_words: bool = False) -> list[str]:
    """The verdict's message, one statement a line, the details with ``verbose`` only.

    :param driver_words: said of a driver's temperature in degrees C, not the paper's codes.
    """
    statements = diagnosis.statements
    texts = ([statement.text for statement in statements if verbose or not statement.detail] if statements
             else [diagnosis.message])
    lines = ['  ' + (in_driver_words(text) if driver_words else text) for text in texts]
    hidden = sum(1 for statement in statements if statement.detail) if not verbose else 0
    if hidden:
        lines.append(f'  ({hidden} more in --verbose and the JSON: the physics behind it, what to do next)')
    return lines


def summary_lines(diagnosis, unit: str, *, label: str = '', verbose: bool = False,
                  driver_words: bool = False) -> list[str]:
    """Everything a diagnosis says of itself, in the order ``tak_calib diagnose`` prints it.

    :param label: put before the verdict (``'gyroscope: '`` of a driver's unit).
    """
    return [*axes_lines(diagnosis, unit), *allan_lines(diagnosis), *search_lines(diagnosis, unit),
            f'{label}verdict: {diagnosis.verdict}',
            *statement_lines(diagnosis, verbose=verbose, driver_words=driver_words)]
