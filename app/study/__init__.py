"""Studies that run many sessions on the sweep engine (:mod:`app.sweep`): the paper's Table I
experiment with a population of operators, and the Z-width of each renderer."""
