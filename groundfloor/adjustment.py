"""The global test of a least-squares adjustment: is the a-posteriori variance factor compatible with 1?

An adjustment with a-priori weights (the inverse covariances of its observations) estimates the
variance factor ``s0^2 = v^T P v / r`` from its residuals ``v`` with ``r`` degrees of freedom
(eq. 2.25). If the a-priori precisions are right and the model holds, ``r s0^2`` follows a
chi-square distribution with ``r`` degrees of freedom, so the two-sided test at level ``alpha``
accepts when ``s0^2`` lies in ``[chi2(alpha/2, r) / r, chi2(1 - alpha/2, r) / r]``. Too small: the
a-priori standard deviations are pessimistic; too large: they are optimistic, or the model
misses something (a blunder, a systematic effect).
"""

from __future__ import annotations

from dataclasses import dataclass

from scipy.stats import chi2


@dataclass(frozen=True)
class VarianceFactorTest:
    """The global (chi-square) test of an a-posteriori variance factor."""

    s0_sq: float  # a-posteriori variance factor
    dof: int  # degrees of freedom (redundancy)
    alpha: float  # level of the two-sided test
    lower: float  # acceptance interval of s0^2
    upper: float
    p_value: float  # two-sided p-value
    verdict: str  # "accepted", "too small" or "too large"

    @property
    def accepted(self) -> bool:
        """True when ``s0^2`` lies inside the acceptance interval."""
        return self.verdict == "accepted"

    def sentence(self) -> str:
        """Return the test in words, e.g. ``s0^2 = 0.14, dof 15: outside [0.42, 1.83] (95 %): a-priori
        standard deviations too pessimistic (factor 2.7)``."""
        level = f"{100 * (1 - self.alpha):g} %"
        head = f"s0^2 = {self.s0_sq:.3g}, dof {self.dof}"
        if self.accepted:
            return f"{head}: inside [{self.lower:.3g}, {self.upper:.3g}] ({level}): accepted"
        factor = self.s0_sq ** -0.5 if self.s0_sq > 0 else float("inf")
        why = (f"a-priori standard deviations too pessimistic (about {factor:.2g} times)" if self.verdict == "too small"
               else f"a-priori standard deviations too optimistic (about {1 / factor:.2g} times) or the model "
                    "misses an effect")
        return f"{head}: outside [{self.lower:.3g}, {self.upper:.3g}] ({level}), rejected: {why}"

    def to_json(self) -> dict:
        """Return the test as JSON values."""
        return {"s0_sq": self.s0_sq, "dof": self.dof, "alpha": self.alpha, "lower": self.lower,
                "upper": self.upper, "p_value": self.p_value, "verdict": self.verdict}


def variance_factor_test(s0_sq: float, dof: int, alpha: float = 0.05) -> VarianceFactorTest:
    """Return the two-sided global test of the a-posteriori variance factor ``s0_sq`` with ``dof`` degrees of freedom."""
    dof = int(dof)
    if dof < 1:
        raise ValueError(f"dof = {dof}: a global test needs at least one degree of freedom")
    lower, upper = (float(q) / dof for q in chi2.ppf([alpha / 2, 1 - alpha / 2], dof))
    omega = float(s0_sq) * dof
    p = float(min(1.0, 2 * min(chi2.cdf(omega, dof), chi2.sf(omega, dof))))
    verdict = "accepted" if lower <= s0_sq <= upper else ("too small" if s0_sq < lower else "too large")
    return VarianceFactorTest(float(s0_sq), dof, alpha, lower, upper, p, verdict)
