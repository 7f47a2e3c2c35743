"""Error bars beyond the Laplace covariance: profile likelihood and emcee posteriors."""
