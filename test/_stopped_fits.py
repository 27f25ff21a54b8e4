"""A ``fit_free`` that reports its final (robust) fit as stopped by its evaluation budget."""


def final_fit_stops(module, monkeypatch):
    """Patch ``module.fit_free`` so that its robust-loss fits come back not converged."""
    real = module.fit_free

    def stopped(resid, std, base, free, with_prior=False, robust=False, **kw):
        p, res = real(resid, std, base, free, with_prior, robust, **kw)
        if robust:
            res.success = False
        return p, res
    monkeypatch.setattr(module, 'fit_free', stopped)
