"""What the data say about the parameters: residual statistics, intervals, the sampled posterior.

* :mod:`.residual`: residuals, the noise level (configured or estimated), the chi-square test noise/structure;
* :mod:`.laplace`: the error model and the Laplace intervals at a least-squares optimum;
* :mod:`.intervals`: Gauss-Newton to that optimum on the FE model, and its intervals;
* :mod:`.posterior`: the linearity check of those intervals and the posterior sampled on the FE model.
"""
