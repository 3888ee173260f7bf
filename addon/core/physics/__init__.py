"""The physics of the core: the cloth and its manipulation (scenario), the models that move it
(paper, and the simulators behind them), with their numba kernels.
"""
