"""Which unmodelled effect causes a sim-to-real gap, and how far the gap shrinks once it is added.

Pipeline of :func:`diagnose_effects`. Two data sets: the **fit** recordings (effects are
fitted there) and the **validation** recordings (effects are ranked and chosen there; carved from
the fit data by :func:`aeropend_ident.io.split.validation_split`). The **held-out** recordings of
:func:`aeropend_ident.gap.run.run_gap` are never seen here.

1. **Validation of the inputs** (:func:`aeropend_ident.gap.effects.check_recordings`): θ and the
   duty cycle present and finite, enough samples; the channels recorded in every recording decide
   which catalog effects are identifiable (:func:`aeropend_ident.gap.effects.identifiable`).
   Noise part of every channel (:func:`_noise_var`: white-noise estimate, at least the
   quantisation floor). When the validation part shows no gap above noise but the fit part does
   after each recording's first second (the stretch never reaches, say, an end stop), the
   effects are ranked on the fit part and the report says so.
2. **Screening by discrepancy SINDy under group sparsity** (:func:`screen`): for each state
   equation that the recorded channels support (θ̈ always; di_a/dt, dω₁/dt and the algebraic
   v_a map when i_a, ω₁, v_a are recorded) the residual of the nominal model,
   r = ẋ_recorded − f_nominal(x), is regressed on the catalog's term groups. The column of an
   effect parameter is the change of the model's right-hand side when it goes from its nominal
   (``off``) value to a typical physical magnitude (``probe``), evaluated on the recorded states.
   Strong form (estimated derivatives) and weak form (test-function integrals of
   :func:`aeropend_ident.sindy.weak_form.weak_matrices`). Whole groups are selected by group orthogonal
   matching pursuit with a BIC stop (:func:`group_select`); a bootstrap over time segments gives
   each group's inclusion frequency. Each effect's own regression coefficient is its
   **equation-error estimate** of the physical parameter.
3. **Confirmation by grey-box output error** (:func:`fit_effects`): each shortlisted effect's
   physical parameters are fitted by free-run output error on every recorded channel (θ, i_a,
   v_a, ω₁, each normalised by its range), over the physical range the rig and the data imply
   (:class:`aeropend_ident.gap.effects.EffectContext`), from several starts (the equation-error
   estimate, a scan of the range, the probe), each refined by
   :func:`scipy.optimize.least_squares` with an absolute-step Jacobian.
4. **Ranking and decision**: candidates are ranked by the share of the nominal validation error
   they remove (an effect that nests a simpler one must beat it by :data:`MIN_EXPLAINED_SECOND`
   of what the simpler one leaves). "No significant gap" when no channel's nominal validation
   error exceeds :data:`ABOVE_NOISE` times its noise part plus the chance margin of its held
   rounding errors (:func:`_rounding_chance`), or when no effect removes
   :data:`MIN_EXPLAINED` of the validation gap above noise with a BIC gain of :data:`MIN_BIC_GAIN`
   on the fit data (and, when the effects are ranked on the fit part because the validation part
   shows no gap, with an in-sample split-test p-value of at most :data:`IN_SAMPLE_MAX_P`).
   Further effects are added by forward selection (:func:`_add_effect`) while
   the chosen set leaves a gap above the noise, up to ``max_effects``.
5. **Two numbers: presence and completeness** (:func:`_evidence`). An effect's **presence**
   (0..1) is the evidence that it is in the plant: a sample-split test of its fit (made on the
   fit part) on the validation part (:func:`split_test`: one-sided t test that it shrinks each
   second's validation error, weighted by the share of that second's error above noise, by more
   than the share the decision asks for, the sample size corrected for the correlation of
   neighbouring seconds),
   against the nominal rig for a single effect and against the set before it for an effect added
   by forward selection; the p-values of every candidate tried are adjusted for
   the false-discovery rate (Benjamini-Hochberg), and presence = (1 − q) × the bootstrap
   frequency (over validation segments) with which the effect wins against the candidates that
   explain the same error (first among the single effects; the added gain passing), times
   0.5 + 0.5·completeness (:func:`misspecification_factor`: a residual left far above the noise
   shows something outside the catalog, for which a passing effect may stand in). So presence
   ≥ 0.9 reads "at a false-discovery rate of 10 %, not a rival's stand-in, and the model leaves
   (nearly) the noise level". **Completeness**
   (:func:`_completeness`: channel by channel, the validation error left over the noise part)
   says how fully the chosen set explains the gap. The words follow from the two by stated
   thresholds (:func:`status_of`): a chosen effect is ``named`` with presence ≥
   :data:`NAMED_PRESENCE` and a set completeness ≥ :data:`NAMED_COMPLETENESS`, otherwise a
   ``candidate`` (a cause outside the catalog leaves a residual far above the noise, whichever
   effect approximates it best); runner-ups that win a share of the resamples, and physics-confusable
   runner-ups neither of which removes :data:`SWAP_GAIN` of what the other leaves
   (:func:`_not_separated`), are ``not separated`` from the first (``ambiguous_with``); others
   are a ``candidate`` with presence ≥ :data:`CANDIDATE_PRESENCE`, else ``not significant``.
6. **Validation table** (:func:`gap_metrics`): NRMSE per channel, max error, steady-state map
   error and step metrics before and after, per cumulative effect set.

Quantisation is detected directly from the recorded angle (values on a lattice of step q,
:func:`aeropend_ident.gap.effects.detect_quantum`): a property of the data, not an effect to fit.
It is reported in ``detected`` (and ranked, marked ``detected``), sets the corrected rig's angle
LSB and the noise floor (q²/12), and never enters ``chosen``, whose effects later steps refit.

A timing effect fitted shorter than half the sample period (:func:`unresolved_times`) is not
resolved at that rate: never chosen (first, added or as a replacement), presence 0, entry field
``unresolved`` with the reason; what such a fit matches is when the logger stamps a channel.

The stages, one module each, in the order they import one another:

=============  ==================================================================================
``data``       the recordings prepared for the fits (:class:`~.data.Prepared`), initial states, replays
``fitting``    grey-box output-error fits of effect parameters (:func:`~.fitting.fit_effects`), covariance
``metrics``    the validation figures (:func:`~.metrics.gap_metrics`, per-segment errors)
``screening``  discrepancy SINDy under group sparsity (:func:`~.screening.screen`)
``context``    the one context of a run (``_Setup``: prepared data, nominal errors, noise parts)
``candidates`` each shortlisted effect fitted alone and scored; completeness
``evidence``   split test, presence, the status words, unresolved timing effects
``ranking``    first effect, forward selection, confusable swaps, refinement
``diagnosis``  :func:`~.diagnosis.diagnose_effects`: the stages in order; :class:`~.diagnosis.EffectDiagnosis`
=============  ==================================================================================

Callers import from the stage module that defines a name; this ``__init__`` re-exports nothing.
No rclpy import: this package runs without ROS.
"""
