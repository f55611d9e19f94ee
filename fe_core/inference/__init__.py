"""What the data say about the parameters: residual statistics, intervals, the sampled posterior.

* :mod:`.residual`: residuals, the noise level (configured or estimated), the chi-square test noise/structure;
* :mod:`.intervals`: Gauss-Newton to the least-squares optimum and the Laplace intervals there;
* :mod:`.posterior`: the linearity check of those intervals and the posterior sampled on the FE model.
"""
