"""What a lab states about its CSV logs: the input kinds (actuator command -> duty cycle), the column
mapping (:class:`~aeropend_ident.io.csvspec.spec.CsvSpec`, preset YAML files) and the check that a
constant input can explain a log (:mod:`~aeropend_ident.io.csvspec.constant_input`)."""
