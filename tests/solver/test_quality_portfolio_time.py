"""The quality portfolio starts its min-Gram engine only where that engine's min-Gram (not
interrupted) ends within the time left: `camplace solve --mode quality --time-limit 0.5` on the
2,000 x 10,000 bunker folder took 24 s (the min-Gram started with no time left), now 0.6 s."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from camplace.solver._support.deadline import Deadline
from camplace.solver.engines.quality import portfolio
from camplace.solver.engines.quality.min_gram import min_gram_cost


def _resid(seed: int = 0) -> sp.csr_matrix:
    rng = np.random.default_rng(seed)
    dense = (rng.random((60, 12)) < 0.5) * rng.choice([0.25, 0.5, 1.0], size=(60, 12))
    return sp.csr_matrix(dense)


def test_min_gram_waits_for_time(monkeypatch) -> None:
    q = _resid()
    terms = min_gram_cost(q)
    assert terms > 0
    monkeypatch.setattr(portfolio, "_MIN_GRAM_TERMS_PER_S", terms / 10.0)  # 10 s of min-Gram
    stats: dict = {}
    assert portfolio._gram_fits(q, Deadline(None), stats) and stats == {}
    assert portfolio._gram_fits(q, Deadline(60.0), stats) and stats == {}
    assert not portfolio._gram_fits(q, Deadline(5.0), stats)
    assert "would take about 10.0 s" in stats["min_gram_skipped"]


def test_an_expired_portfolio_returns_the_tree_answer_without_the_min_gram(monkeypatch) -> None:
    q = _resid(1)
    w = np.ones(q.shape[0])
    monkeypatch.setattr(portfolio, "solve_quality_exact", lambda *a, **k: pytest.fail("min-Gram started"))
    monkeypatch.setattr(portfolio, "_MIN_GRAM_TERMS_PER_S", min_gram_cost(q) / 10.0)
    stats: dict = {}
    value = lambda sel: float(w @ q[:, list(sel)].toarray().max(axis=1))  # noqa: E731
    out = portfolio.quality_engines(q, w, 3, True, True, (), np.arange(q.shape[1]), value, 0.0, Deadline(1e-9), stats)
    assert out.status in ("optimal", "feasible") and len(out.selected) == 3
    assert out.bound >= out.objective - 1e-12 and stats["quality_engines"] == ["tree"]
