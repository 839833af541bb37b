"""The two forms of the operator DAE a run discretizes, as validated objects.

In both forms a step is the stationary problem for the scheme's unknown x^j
(:mod:`rothe.eld.stepper`, :mod:`rothe.eld.system`):

:class:`Original` -- (2.7) discretized directly, index 3: x = u, with y^j = delta_j u
    (velocity) and a^j = delta_j y (acceleration),
        rho M a^j + D(y^j) + K u^j + B^T lambda^j = F^j,      B u^j = G^j,
    one (nonlinear if D is) saddle-point system for (u^j, lambda^j).

:class:`Regularized` -- the index-1 form (2.8), with the structure of Sec. 3:
        u_2^j = B^- G^j,  v_2^j = B^- G_dot^j,  w_2^j = B^- G_ddot^j           (3.4b)
    (the lifting: the data at t_j, whatever the steps), x = u_1^j in V_B = ker B with
    y^j = delta_j u_1 and b^j = delta_j y from
        rho M (b^j + w_2^j) + D(y^j + v_2^j) + K (u_1^j + u_2^j) = F^j   tested with V_B,
    and lambda^j from the same equation tested with V^c
    (:meth:`DirichletConstraint.multiplier_from_residual`). u = u_1 + u_2, v = y + v_2 (the
    velocity the damping sees), a = b + w_2. B^- is a fixed right inverse of B
    (:mod:`rothe.eld.constraint`): ``lifting='nodal'`` (default) or ``'harmonic'``.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import check_choice, check_instance
from .constraint import LIFTINGS


class Form:
    """The form of the DAE a run discretizes (module docstring): :class:`Regularized` or
    :class:`Original`.

    Attributes
    ----------
    name : str
        ``'regularized'`` or ``'original'`` (as in trajectories, summaries and on the command
        line).
    lifting : str or None
        The right inverse B^- of the regularized form (None in the original form).
    """

    name: str = ""
    lifting: str | None = None

    def describe(self) -> dict:
        """The form as in the trajectory's meta data: ``form`` and ``lifting``."""
        return {"form": self.name, "lifting": self.lifting}


@dataclass(frozen=True)
class Regularized(Form):
    """The regularized form (2.8), index 1 (module docstring); the default.

    Parameters
    ----------
    lifting : {'nodal', 'harmonic'}
        The right inverse B^- of the trace: ``'nodal'`` (default; B^-(M_G g) = S^T g, zero at
        every node off Gamma_D) or ``'harmonic'`` (the discrete elastic extension, the paper's
        K-orthogonal complement of ker B; :mod:`rothe.eld.constraint`).
    """

    lifting: str = "nodal"
    name = "regularized"

    def __post_init__(self):
        check_choice("lifting", self.lifting, LIFTINGS)


@dataclass(frozen=True)
class Original(Form):
    """The original form (2.7), index 3: one saddle-point system for (u^j, lambda^j) per step
    (module docstring); solved by condensing the constraint (:mod:`rothe.eld.solvers`)."""

    name = "original"


#: the form of a run that names none
DEFAULT_FORM = Regularized()


def as_form(form) -> Form:
    """``form`` if it is a :class:`Form`, else a one-line error naming ``form``."""
    return check_instance(
        "form", form, Form, "Regularized(lifting=...) or Original() (rothe.eld.form)"
    )
