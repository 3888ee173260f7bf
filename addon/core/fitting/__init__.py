"""Fitting a model to a capture: the objective, the optimisers, the steppable fit job, scoring."""
