"""Experiment design (issue 63): the recording that separates a gap diagnosis' candidates or
determines the parameters a ``rig fit`` left undetermined, within a rig's limits.

Modules (import them directly; docs/design.md):

* :mod:`aeropend_ident.design.sequence` -- ``Limits``, ``AprbsShape``, ``sequence``, ``check_limits``
* :mod:`aeropend_ident.design.candidates` -- ``diagnosis_candidates``, ``candidate_sets``,
  ``fit_candidates``, ``channel_noise``
* :mod:`aeropend_ident.design.discriminate` -- ``design_discrimination``, ``rank_first_probability``,
  ``evidence``
* :mod:`aeropend_ident.design.parameters` -- ``design_parameters`` (Ds-/D-optimal), ``weak_keys``
* :mod:`aeropend_ident.design.report` -- ``write_design``, ``compare_outcome``
* :mod:`aeropend_ident.design.cli` -- ``excitation_design`` / ``excitation --design-for``

Example::

    from aeropend_ident.design.candidates import channel_noise, diagnosis_candidates
    from aeropend_ident.design.discriminate import design_discrimination
    from aeropend_ident.design.sequence import AprbsShape, Limits

    cands, _ = diagnosis_candidates(result.diagnosis.as_dict(), rig, fit_recordings)   # a GapResult
    sigma = channel_noise(fit_recordings, ["theta"])
    limits = Limits.from_recordings([r.channels["theta"] for r in fit_recordings],
                                    [r.duty for r in fit_recordings], fit_recordings[0].dt)
    design = design_discrimination(cands, sigma, limits, AprbsShape.for_duration(40.0), seed=0)
    design.duty                                                              # (N,) commands
"""
