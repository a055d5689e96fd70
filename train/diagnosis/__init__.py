"""Which physics is a model missing: the ranking of the effects library's candidates by the held-out
error each removes (diagnose, with its cross-validation cv, the effect interface it reads effects,
ranking, result, text and defaults), the discovery of a term the library lacks (discovery,
discovery_basis, discovery_select) and the effect file written from it (effect_writer).

The defaults live in their own module (defaults) so that `--help` reads them without numpy; importing
this package imports nothing else."""
