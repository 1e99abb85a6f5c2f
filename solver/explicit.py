r"""Total Lagrangian explicit dynamics of the platen compression test.

The time loop (Miller et al. 2007): internal forces from the reference-configuration operators
of :mod:`solver.kernels` (axisymmetric quads or 3D hexahedra: :func:`simulate` dispatches on
the mesh's cell type, and both share the nodal update, the platen constraints, the set-up and
the checks), lumped or volumetric masses, central differences

.. math::

    v^{n+1/2} = v^{n-1/2} + \Delta t^{n} M^{-1} (f_c^n - f_{int}^n), \qquad
    u^{n+1} = u^n + \Delta t^{n+1/2} v^{n+1/2},

and kinematic platen constraints. Every boundary node is a contact candidate for the two rigid
platens, so free-surface nodes that bulge out and roll onto a platen (from about 15 %
compression, Morriss et al. 2007) cannot pass through it; with bonded platens they stick where
they land.

Quasi-static runs. The rig tests are quasi-static, so the run only has to be slow compared with
the sample's lowest natural period :math:`T_1`. The ramp keeps its real duration (a
viscoelastic material sees the real test time) and the *mass* is scaled (never the time): the
density is chosen such that :math:`T / T_1` equals ``quasi_static_ratio`` (:math:`T_1` of the
lowest mode the platen's motion excites: a 3D model's lower torsion, sway and ovalling modes
are orthogonal to the axisymmetric load, see :func:`solver.stiffness.lowest_mode`), and
elements whose own stable step is far below the typical one get extra mass (selective mass
scaling). Axisymmetric bonded and frictionless runs add mass to each element's volumetric
deformation alone (:mod:`solver.mass`): the step then follows the shear waves, not the
pressure waves that a gel at :math:`\nu = 0.499` carries 22 times faster, while the lowest,
isochoric mode keeps its period. That mass matrix is not diagonal; the held DOFs take the
accelerations the constraints prescribe and the free ones solve
:math:`M_{ff} a_f = -f_f - M_{fh} a_h` (:func:`_coupled_update`). The stable step comes from
the exact element bound of the mass-scaled pencil at the start and from Lanczos on the
tangent along the ramp (lumped masses: an element bound grown with each element's shape and
tangent). Coulomb runs (lumped masses) damp their volumetric ringing with a linear bulk
viscosity (:mod:`solver.viscosity`), without which the stick-slip decisions turn it into extra,
ramp-dependent slip. The
platen force is then evaluated by virtual work in the static influence field :math:`w` (the
displacement per unit travel of the linearised problem),

.. math::

    P = \sum_i f^{int}_i \cdot w_i - \sum_{i \in \text{contact}} f^{c}_{t,i}\, w_{t,i},

which equals the platen reaction minus the virtual work :math:`w \cdot M a` of the inertia
forces; in linear elastodynamics this removes the inertia from the force exactly (with any
mass matrix), at finite strain to first order. The raw platen reaction is reported as well.

Scaling. With Poisson's ratio fixed and the ramp set relative to :math:`T_1`, the run for a
material whose moduli are all multiplied by :math:`c` is the same run with every force times
:math:`c`: the step count and sizes are computed from moduli normalised by the first
material's shear modulus, and the density scales with the moduli. Hence
:math:`F(d; \mu, \alpha, \nu) = \mu f(d; \alpha, \nu)` to rounding, which the calibration uses
to eliminate :math:`\mu`.

References
----------
Morriss L, Wittek A, Miller K (2008). Compression testing of very soft biological tissues
using semi-confined configuration: a word of caution. J Biomech 41:235-238.
doi:10.1016/j.jbiomech.2007.06.025
"""

from __future__ import annotations

import collections
import dataclasses
import math
import threading
import time
from collections.abc import Sequence

import numpy as np
import scipy.sparse as sp

from ._jit import njit, njit_inline
from .kernels import (
    INVERTED,
    NOT_FINITE,
    OK,
    axisym_energy,
    axisym_forces,
    axisym_stiffening,
    axisym_stress,
    axisymmetric_operators,
    hex_energy,
    hex_forces,
    hex_forces_serial,
    hex_operators,
    hex_stiffening,
    hex_stress,
    node_slots,
)
from .loading import CompressionTest, travel
from .mass import (
    VolumetricMass,
    added_mass_matrix,
    apply_inverse,
    apply_mass,
    assemble_band,
    band_cholesky,
    element_dot,
    volumetric_drift,
    volumetric_gradient,
)
from .materials import Ogden
from .mesh import Mesh, axisymmetric_cylinder
from .stiffness import (
    TangentProbe,
    assemble,
    element_max_frequency_sq,
    element_max_frequency_sq_coupled,
    element_stiffness,
    factorize,
    influence_field,
    lanczos_max,
    lowest_mode,
)
from .viscosity import (
    DEFAULT_BULK_VISCOSITY,
    bulk_viscosity_coefficient,
    bulk_viscosity_forces,
    hex_bulk_viscosity_forces,
    step_factor,
)

__all__ = ["simulate", "SimulationResult", "SolverInstability", "DEFAULT_QUASI_STATIC_RATIO"]

#: Default ramp time over the lowest natural period (see the quasi-static tests).
DEFAULT_QUASI_STATIC_RATIO = 6.0
#: Default with Coulomb platens (see ``quasi_static_ratio`` of :func:`simulate`).
COULOMB_QUASI_STATIC_RATIO = 10.0

#: Intervals along the ramp between checks of the stable step with the volumetric mass.
_STEP_CHECKS = 5
#: Contact states of a node.
FREE, BOTTOM, TOP = 0, 1, 2
#: Status of a run whose volumetric mass matrix lost positive definiteness (beside the
#: kernel codes of :mod:`solver.kernels`).
MASS_NOT_DEFINITE = 3
#: Platen modes of the kernel.
BONDED, FRICTIONLESS, COULOMB = 0, 1, 2
_MODE = {"bonded": BONDED, "frictionless": FRICTIONLESS, "coulomb": COULOMB}


class SolverInstability(RuntimeError):
    """An explicit run that went unstable: where, when and why.

    Attributes
    ----------
    reason : str
    step : int
    time_s : float
    travel_mm : float
    element : int or None
    """

    def __init__(self, reason: str, step: int, time_s: float, travel_mm: float,
                 element: int | None = None):
        self.reason = reason
        self.step = step
        self.time_s = time_s
        self.travel_mm = travel_mm
        self.element = element
        where = "" if element is None else f" in element {element}"
        super().__init__(
            f"explicit run stopped at step {step} (t = {time_s:.6g} s, platen travel "
            f"{travel_mm:.4f} mm): {reason}{where}"
        )

    def __reduce__(self):
        # picklable with its attributes, so it crosses process pools intact
        return (type(self), (self.reason, self.step, self.time_s, self.travel_mm,
                             self.element))


@dataclasses.dataclass(frozen=True)
class SimulationResult:
    """Force-travel curve, energies and final state of one explicit run.

    Attributes
    ----------
    time_s, displacement_mm, force_N : ndarray, shape (n_out,)
        Time (s), platen travel (mm), and the quasi-static platen force (N, compression
        positive) evaluated by virtual work in the influence field (inertia removed).
    reaction_N : ndarray, shape (n_out,)
        Raw top-platen reaction (N), inertia of the sample included.
    bottom_reaction_N : ndarray, shape (n_out,)
        Reaction on the fixed bottom platen (N).
    energy : dict of ndarray, shape (n_out,)
        ``external_J`` (work of the platen constraints), ``internal_J`` (path integral of the
        internal forces), ``strain_J`` (elastic energy stored in the state, long-term moduli),
        ``hourglass_J``, ``kinetic_J``, ``friction_J`` (work of friction forces, <= 0),
        ``damping_J`` (energy taken out by the hold's damping and the bulk viscosity, >= 0;
        zero with neither).
    contact_radius_mm : ndarray, shape (n_out,)
        Current radius of the contact area on the top platen (mm).
    mesh : Mesh
        Reference mesh.
    displacement_m : ndarray, shape (n_nodes, dim)
        Final nodal displacements (m).
    n_steps : int
    dt_s : float
        Initial time step (s).
    natural_period_s : float
        Lowest natural period of the (mass-scaled) sample (s).
    quasi_static_ratio : float
        Ramp time over the natural period.
    density_kg_m3 : float
        Density used in the run (after mass scaling).
    added_mass_fraction : float
        Lumped mass added to the smallest elements over the total mass.
    volumetric_mass : bool
        Whether the run used the volumetric selective mass (:mod:`solver.mass`).
    notes : tuple of str
        What the solver did beyond the asked (a rerun with lumped masses, and why).
    wall_s : float
        Wall-clock time of the time loop (s).
    cell_stress_Pa : ndarray, shape (n_cells, 6)
        Cauchy stress of every element in the final state (Pa), components (xx, yy, zz, xy,
        yz, xz); for the axisymmetric section x = r, y = hoop, z = axis.
    """

    time_s: np.ndarray
    displacement_mm: np.ndarray
    force_N: np.ndarray
    reaction_N: np.ndarray
    bottom_reaction_N: np.ndarray
    energy: dict
    contact_radius_mm: np.ndarray
    mesh: Mesh
    displacement_m: np.ndarray
    n_steps: int
    dt_s: float
    natural_period_s: float
    quasi_static_ratio: float
    density_kg_m3: float
    added_mass_fraction: float
    wall_s: float
    cell_stress_Pa: np.ndarray | None = None
    volumetric_mass: bool = False
    notes: tuple = ()

    @property
    def deformed_points_m(self) -> np.ndarray:
        """Final nodal coordinates (m)."""
        return self.mesh.points + self.displacement_m

    @property
    def kinetic_ratio(self) -> float:
        """Largest kinetic over stored (strain + hourglass) energy beyond 5 % of the travel."""
        stored = self.energy["strain_J"] + self.energy["hourglass_J"]
        later = self.displacement_mm >= 0.05 * self.displacement_mm[-1]
        return float(np.max(self.energy["kinetic_J"][later] / stored[later]))

    @property
    def hourglass_ratio(self) -> float:
        """Hourglass over strain energy at the end of the run."""
        return float(self.energy["hourglass_J"][-1] / self.energy["strain_J"][-1])

    def von_mises_Pa(self) -> np.ndarray:
        """Von Mises equivalent of :attr:`cell_stress_Pa`, shape (n_cells,) (Pa)."""
        s = self.cell_stress_Pa
        normal = (s[:, 0] - s[:, 1]) ** 2 + (s[:, 1] - s[:, 2]) ** 2 + (s[:, 2] - s[:, 0]) ** 2
        shear = s[:, 3] ** 2 + s[:, 4] ** 2 + s[:, 5] ** 2
        return np.sqrt(0.5 * normal + 3.0 * shear)

    def write_vtk(self, path) -> None:
        """Write the deformed mesh with its fields as VTK (meshio; see :mod:`solver.output`)."""
        from .output import write_vtk

        write_vtk(self, path)

    def write_png(self, path) -> None:
        """Draw the deformed section and the force curve to a PNG (see :mod:`solver.output`)."""
        from .output import write_png

        write_png(self, path)

    def to_frame(self):
        """The curve as a pandas DataFrame (``time_s``, ``displacement_mm``, ``force_N``, ...)."""
        import pandas as pd

        data = {"time_s": self.time_s, "displacement_mm": self.displacement_mm,
                "force_N": self.force_N, "reaction_N": self.reaction_N,
                "bottom_reaction_N": self.bottom_reaction_N,
                "contact_radius_mm": self.contact_radius_mm}
        data.update(self.energy)
        return pd.DataFrame(data)


# ====================================================================== JIT time loop
@njit
def _nodal_update(
    u,  # (n_nodes, dim) displacement at t_n, replaced by u^{n+1}
    v,  # (n_nodes, dim) velocity v^{n-1/2}, replaced by v^{n+1/2}
    f_int,  # (n_nodes, dim) internal forces at t_n
    f_v,  # (n_nodes, dim) bulk-viscous forces at t_n (their work is damping work)
    f_c,  # (n_nodes, dim) output: constraint forces at t_n
    mass,  # (n_nodes,)
    X,  # (n_nodes, dim) reference coordinates (m)
    fix_tangent,  # (n_nodes,) bool: tangential DOFs held (axis of symmetry)
    state,  # (n_nodes,) int8 contact state FREE/BOTTOM/TOP (updated)
    glued,  # (n_nodes,) bool: bonded face nodes, never released
    candidate,  # (n_nodes,) bool: may come into contact
    anchor,  # (n_nodes, dim) tangential position held while sticking (updated)
    mode,  # BONDED / FRICTIONLESS / COULOMB
    mu_f,  # friction coefficient
    z_top,  # height of the top platen at t_{n+1} (m)
    dt,  # step t_n -> t_{n+1} (s)
    dt_avg,  # (dt_prev + dt) / 2 (s)
    damp,  # mass-proportional damping (1/s), zero while the platen moves
    energy,  # (4,) accumulated internal, constraint, friction and damping work (J)
):
    """Central-difference update of every node with kinematic platen constraints."""
    n_nodes, dim = u.shape
    nz = dim - 1
    w_int = 0.0
    w_c = 0.0
    w_f = 0.0
    w_d = 0.0
    for i in range(n_nodes):
        m = mass[i]
        scale = dt * dt_avg / m  # displacement per unit force over this step
        # trial (unconstrained) update
        for a in range(dim):
            f_c[i, a] = 0.0
        zt = u[i, nz] + dt * (v[i, nz] - dt_avg * ((f_int[i, nz] + f_v[i, nz]) / m
                                                  + damp * v[i, nz]))
        z_new = X[i, nz] + zt
        st = state[i]
        if st == FREE and candidate[i]:
            if z_new < 0.0:
                st = BOTTOM
            elif z_new > z_top:
                st = TOP
            if st != FREE:
                for a in range(nz):
                    anchor[i, a] = u[i, a] + dt * (
                        v[i, a] - dt_avg * ((f_int[i, a] + f_v[i, a]) / m + damp * v[i, a]))
        if st != FREE:
            target = -X[i, nz] if st == BOTTOM else z_top - X[i, nz]
            fz = (target - zt) / scale
            # release a node the platen would have to pull (no adhesion off the glued faces)
            if not glued[i] and ((st == BOTTOM and fz < 0.0) or (st == TOP and fz > 0.0)):
                st = FREE
            else:
                f_c[i, nz] = fz
        state[i] = st
        # tangential directions
        fn = abs(f_c[i, nz])
        trial_t = 0.0
        stick_t = 0.0
        for a in range(nz):
            ut = u[i, a] + dt * (v[i, a] - dt_avg * ((f_int[i, a] + f_v[i, a]) / m
                                                     + damp * v[i, a]))
            if fix_tangent[i]:
                f_c[i, a] = -ut / scale
            elif st != FREE and mode != FRICTIONLESS:
                f_c[i, a] = (anchor[i, a] - ut) / scale
            trial_t += f_c[i, a] * f_c[i, a]
        if st != FREE and mode == COULOMB and not fix_tangent[i]:
            stick_t = math.sqrt(trial_t)
            if stick_t > mu_f * fn:  # slip: friction at its limit, against the trial slip
                ratio = mu_f * fn / stick_t
                for a in range(nz):
                    f_c[i, a] *= ratio
        # apply: u^{n+1} = trial + scale f_c ; v^{n+1/2} = (u^{n+1} - u^n) / dt
        for a in range(dim):
            v_old = v[i, a]
            f_d = damp * m * v_old + f_v[i, a]
            v_new = v_old - dt_avg * (f_int[i, a] + f_d - f_c[i, a]) / m
            u[i, a] += dt * v_new
            v[i, a] = v_new
            delta = 0.5 * dt_avg * (v_new + v_old)
            w_int += f_int[i, a] * delta
            w_c += f_c[i, a] * delta
            w_d += f_d * delta
            if a < nz and st != FREE and mode == COULOMB:
                w_f += f_c[i, a] * delta
        if st != FREE and mode == COULOMB and stick_t > mu_f * fn:
            for a in range(nz):
                anchor[i, a] = u[i, a]
    energy[0] += w_int
    energy[1] += w_c
    energy[2] += w_f
    energy[3] += w_d


@njit
def _held(fix_tangent, state, mode, held):
    """Which DOFs the platens and the axis hold (n_nodes, 2): the rest move freely."""
    for n in range(state.shape[0]):
        touching = state[n] != FREE
        held[n, 0] = fix_tangent[n] or (touching and mode == BONDED)
        held[n, 1] = touching


@njit
def _refresh_mass(u, conn, bbar, hbar, mass, fix_tangent, state, mode, held, everywhere,
                  coefficient, position, ptr, slot, grad_full, grad, band, full):
    """Volumetric mass at the current contact set, and at the current state if ``full``.

    ``grad_full`` holds :math:`b_e` on every DOF (``everywhere`` is an all-true mask): the
    mass matrix. ``grad`` holds it on the DOFs that move freely, and ``band`` the factor of
    the Woodbury system of their free-free block (see :mod:`solver.mass`).

    Returns
    -------
    int
        -1, or the band row whose Cholesky pivot was not positive.
    """
    _held(fix_tangent, state, mode, held)
    if full:
        volumetric_gradient(u, conn, bbar, hbar, everywhere, coefficient, grad_full)
    for e in range(conn.shape[0]):
        for a in range(4):
            n = conn[e, a]
            for d in range(2):
                grad[e, a, d] = 0.0 if held[n, d] else grad_full[e, a, d]
    assemble_band(grad, mass, coefficient, position, ptr, slot, band)
    return band_cholesky(band)


@njit
def _coupled_update(
    u,  # (n_nodes, 2) displacement at t_n, replaced by u^{n+1}
    v,  # (n_nodes, 2) velocity v^{n-1/2}, replaced by v^{n+1/2}
    f_int,  # (n_nodes, 2) internal forces at t_n
    f_c,  # (n_nodes, 2) output: constraint forces at t_n
    mass,  # (n_nodes,) lumped masses
    X,  # (n_nodes, 2) reference coordinates (m)
    fix_tangent,  # (n_nodes,) bool: radial DOF held (axis of symmetry)
    state,  # (n_nodes,) int8 contact state FREE/BOTTOM/TOP (updated)
    glued,  # (n_nodes,) bool: bonded face nodes, never released
    candidate,  # (n_nodes,) bool: may come into contact
    anchor,  # (n_nodes, 2) radial position held while stuck (updated)
    mode,  # BONDED / FRICTIONLESS
    z_top,  # height of the top platen at t_{n+1} (m)
    dt,  # step t_n -> t_{n+1} (s)
    dt_avg,  # (dt_prev + dt) / 2 (s)
    damp,  # mass-proportional damping (1/s), zero while the platen moves
    energy,  # (4,) accumulated internal, constraint, friction and damping work (J)
    conn, bbar, hbar,  # mesh and operators, as in the force kernel
    held,  # (n_nodes, 2) bool work array: held DOFs of the current contact set
    everywhere,  # (n_nodes, 2) bool, all true
    coefficient, position, ptr, slot,  # fixed part of the volumetric mass (solver.mass)
    grad_full,  # (n_elem, 4, 2) b_e on every DOF at the last refresh
    grad,  # (n_elem, 4, 2) b_e on the free DOFs of the current contact set
    band,  # (n_elem, kd + 1) factor of the free-free Woodbury system
    y,  # (n_elem,) work array
    acc,  # (n_nodes, 2) work array: accelerations without damping
    rhs,  # (n_nodes, 2) work array
):
    r"""Central-difference step with the volumetric mass matrix and kinematic platens.

    The held DOFs (platen contact, axis) get the accelerations that put them where the
    constraint wants them at :math:`t_{n+1}`; the free DOFs solve
    :math:`M_{ff} a_f = -f_f - M_{fh} a_h`, and the constraint forces are
    :math:`f_c = M_{hh} a_h + M_{hf} a_f + f_h`, with one mass matrix whatever the contact set
    (a node that lands or leaves changes which block it is in, not the matrix). A free
    candidate node whose trial position crosses a platen lands; a touching node off the
    glued faces that the platen would have to pull is released; the step is solved again
    until the contact set settles (at most eight times). Bonded and frictionless platens.

    Returns
    -------
    int
        -1, or the band row whose Cholesky pivot was not positive.
    """
    n_nodes = u.shape[0]
    n_elem = conn.shape[0]
    for attempt in range(8):
        # accelerations of the held DOFs (without the damping term, which acts on all)
        for i in range(n_nodes):
            for d in range(2):
                if not held[i, d]:
                    acc[i, d] = 0.0
                    continue
                if d == 1:
                    target = -X[i, 1] if state[i] == BOTTOM else z_top - X[i, 1]
                elif fix_tangent[i]:
                    target = 0.0
                else:
                    target = anchor[i, 0]
                acc[i, d] = ((target - u[i, d]) / dt - v[i, d]) / dt_avg + damp * v[i, d]
        # right side of the free DOFs: -f - M_fh a_h (the added mass couples them)
        for i in range(n_nodes):
            rhs[i, 0] = -f_int[i, 0]
            rhs[i, 1] = -f_int[i, 1]
        for e in range(n_elem):
            s = 0.0
            for a in range(4):
                n = conn[e, a]
                for d in range(2):
                    if held[n, d]:
                        s += grad_full[e, a, d] * acc[n, d]
            if s != 0.0:
                s *= coefficient[e]
                for a in range(4):
                    n = conn[e, a]
                    for d in range(2):
                        rhs[n, d] -= grad_full[e, a, d] * s
        # free DOFs: M_ff^-1 by Woodbury (grad is zero on held DOFs)
        apply_inverse(rhs, conn, mass, grad, position, band, y, f_c)
        for i in range(n_nodes):
            for d in range(2):
                if not held[i, d]:
                    acc[i, d] = f_c[i, d]
        # y[e] = a_e b_e . a: the added-mass force of each element, for the held forces
        for e in range(n_elem):
            y[e] = coefficient[e] * element_dot(e, grad_full, acc, conn)
        if attempt == 7:
            break
        # contact changes: landing free nodes, and touching ones the platen would pull
        changed = False
        for i in range(n_nodes):
            if state[i] == FREE:
                if not candidate[i]:
                    continue
                zt = u[i, 1] + dt * (v[i, 1] + dt_avg * (acc[i, 1] - damp * v[i, 1]))
                z_new = X[i, 1] + zt
                if z_new < 0.0 or z_new > z_top:
                    state[i] = BOTTOM if z_new < 0.0 else TOP
                    anchor[i, 0] = u[i, 0] + dt * (v[i, 0] + dt_avg * (acc[i, 0]
                                                                       - damp * v[i, 0]))
                    changed = True
            elif not glued[i]:
                fz = _held_force(i, 1, acc, f_int, mass, conn, grad_full, y, ptr, slot)
                if (state[i] == BOTTOM and fz < 0.0) or (state[i] == TOP and fz > 0.0):
                    state[i] = FREE
                    changed = True
        if not changed:
            break
        if _refresh_mass(u, conn, bbar, hbar, mass, fix_tangent, state, mode, held,
                         everywhere, coefficient, position, ptr, slot, grad_full, grad, band,
                         False) >= 0:
            return 0
    # constraint forces on the held DOFs, then the update
    w_int = 0.0
    w_c = 0.0
    w_d = 0.0
    for i in range(n_nodes):
        for d in range(2):
            f_c[i, d] = (_held_force(i, d, acc, f_int, mass, conn, grad_full, y, ptr, slot)
                         if held[i, d] else 0.0)
            v_old = v[i, d]
            v_new = v_old + dt_avg * (acc[i, d] - damp * v_old)
            u[i, d] += dt * v_new
            v[i, d] = v_new
            delta = 0.5 * dt_avg * (v_new + v_old)
            w_int += f_int[i, d] * delta
            w_c += f_c[i, d] * delta
            w_d += damp * mass[i] * v_old * delta
    energy[0] += w_int
    energy[1] += w_c
    energy[3] += w_d
    return -1


@njit_inline
def _held_force(i, d, acc, f_int, mass, conn, grad_full, y, ptr, slot):
    """Constraint force on DOF (i, d): (M a)_id + f_id, with y[e] = a_e b_e . a."""
    f = mass[i] * acc[i, d] + f_int[i, d]
    for k in range(ptr[i], ptr[i + 1]):
        e = slot[k] // 4
        f += grad_full[e, slot[k] % 4, d] * y[e]
    return f


@njit
def _advance_axisym(
    t_stop, t, dt, dt_prev, kind, T, D, t_table, d_table, H, hold_damping,
    u, v, f_int, f_c, mass, X, fix_tangent, state, glued, candidate, anchor, mode, mu_f,
    conn, bbar, hbar, vol, gamma, k_hg, mat, mu, alpha, K, g, decay, gain, s_prev, hist,
    u_eval, energy, use_vm, vm, drift, c_bv, grad_bv, f_v,
):
    """Step the axisymmetric model until the last force evaluation reaches ``t_stop``.

    With ``use_vm`` the steps take the volumetric mass (:func:`_coupled_update`; ``vm`` holds
    its arrays, :class:`_VolumetricArrays`), refreshed to the current state once an
    element's volumetric frequency has grown past ``drift`` times its design value
    (:func:`solver.mass.volumetric_drift`). Without it, ``c_bv`` holds the bulk-viscosity
    coefficients (:mod:`solver.viscosity`; empty: none), ``grad_bv`` a work array of their
    volume gradients and ``f_v`` their forces.

    Returns
    -------
    status, element : int
        Kernel status and offending element (see :mod:`solver.kernels`).
    t_eval : float
        Time of the last force evaluation (s); ``u_eval``, ``f_int`` and ``f_c`` hold that
        state on return.
    t, dt_prev : float
        Time and step size to continue from.
    steps : int
        Steps taken.
    """
    held, everywhere, coef, pos, ptr, slot, grad_full, grad, band, y, acc, rhs, share, b_now = vm
    steps = 0
    t_eval = t
    while True:
        status, elem = axisym_forces(u, conn, bbar, hbar, vol, gamma, k_hg, mat, mu, alpha, K,
                                     g, decay, gain, s_prev, hist, True, f_int)
        if status != OK:
            return status, elem, t, t, dt_prev, steps
        u_eval[:] = u
        t_eval = t
        z_top = H - travel(t + dt, kind, T, D, t_table, d_table)
        damp = hold_damping if t >= T else 0.0
        if use_vm:
            if volumetric_drift(u, conn, bbar, hbar, grad_full, share, coef, everywhere,
                                b_now) > drift:
                if _refresh_mass(u, conn, bbar, hbar, mass, fix_tangent, state, mode, held,
                                 everywhere, coef, pos, ptr, slot, grad_full, grad, band,
                                 True) >= 0:
                    return MASS_NOT_DEFINITE, -1, t, t, dt_prev, steps
            if _coupled_update(u, v, f_int, f_c, mass, X, fix_tangent, state, glued, candidate,
                               anchor, mode, z_top, dt, 0.5 * (dt_prev + dt), damp, energy,
                               conn, bbar, hbar, held, everywhere, coef, pos, ptr, slot,
                               grad_full, grad, band, y, acc, rhs) >= 0:
                return MASS_NOT_DEFINITE, -1, t, t, dt_prev, steps
        else:
            if c_bv.shape[0] > 0:
                bulk_viscosity_forces(u, v, conn, bbar, hbar, c_bv, everywhere, grad_bv, f_v)
            _nodal_update(u, v, f_int, f_v, f_c, mass, X, fix_tangent, state, glued,
                          candidate, anchor, mode, mu_f, z_top, dt, 0.5 * (dt_prev + dt), damp,
                          energy)
        dt_prev = dt
        t = t + dt
        steps += 1
        if t_eval >= t_stop - 0.5 * dt:
            return OK, -1, t_eval, t, dt_prev, steps


@njit
def _advance_hex(
    t_stop, t, dt, dt_prev, kind, T, D, t_table, d_table, H, hold_damping,
    u, v, f_int, f_c, mass, X, fix_tangent, state, glued, candidate, anchor, mode, mu_f,
    conn, bbar, vol, gamma, k_hg, mat, mu, alpha, K, g, decay, gain, s_prev, hist,
    ptr, slot, fe, status_e, fe1, parallel, u_eval, energy, c_bv, grad_bv, f_v,
):
    """Step the hexahedral model until the last force evaluation reaches ``t_stop``.

    The same loop as :func:`_advance_axisym` with the hexahedron's force kernel:
    :func:`solver.kernels.hex_forces` (threads; work arrays ``ptr``, ``slot``, ``fe``,
    ``status_e``) if ``parallel`` else :func:`solver.kernels.hex_forces_serial` (work array
    ``fe1``). Returns the same tuple.
    """
    steps = 0
    t_eval = t
    while True:
        if parallel:
            status, elem = hex_forces(u, conn, bbar, vol, gamma, k_hg, mat, mu, alpha, K, g,
                                      decay, gain, s_prev, hist, True, ptr, slot, fe, status_e,
                                      f_int)
        else:
            status, elem = hex_forces_serial(u, conn, bbar, vol, gamma, k_hg, mat, mu, alpha,
                                             K, g, decay, gain, s_prev, hist, True, fe1, f_int)
        if status != OK:
            return status, elem, t, t, dt_prev, steps
        u_eval[:] = u
        t_eval = t
        z_top = H - travel(t + dt, kind, T, D, t_table, d_table)
        damp = hold_damping if t >= T else 0.0
        if c_bv.shape[0] > 0:
            hex_bulk_viscosity_forces(u, v, conn, bbar, c_bv, grad_bv, f_v)
        _nodal_update(u, v, f_int, f_v, f_c, mass, X, fix_tangent, state, glued, candidate,
                      anchor, mode, mu_f, z_top, dt, 0.5 * (dt_prev + dt), damp, energy)
        dt_prev = dt
        t = t + dt
        steps += 1
        if t_eval >= t_stop - 0.5 * dt:
            return OK, -1, t_eval, t, dt_prev, steps


# ====================================================================== set-up
def _material_tables(materials: Sequence[Ogden], n_mat: int):
    n_terms = max(m.n_terms for m in materials)
    n_prony = max(0 if m.prony is None else len(m.prony.g) for m in materials)
    mu = np.zeros((n_mat, n_terms))
    mu_lt = np.zeros((n_mat, n_terms))
    alpha = np.ones((n_mat, n_terms))
    K = np.zeros(n_mat)
    g = np.zeros((n_mat, n_prony))
    tau = np.ones((n_mat, n_prony))
    for k, m in enumerate(materials):
        mu_k, alpha_k, K_k, g_k, tau_k = m.kernel_arrays()
        mu[k, : m.n_terms] = mu_k
        mu_lt[k, : m.n_terms] = m.mu_Pa
        alpha[k, : m.n_terms] = alpha_k
        K[k] = K_k
        g[k, : len(g_k)] = g_k
        tau[k, : len(tau_k)] = tau_k
    return mu, mu_lt, alpha, K, g, tau


def _prony_factors(tau, dt):
    """Decay exp(-dt/tau) and gain (1 - exp(-dt/tau)) / (dt/tau) of the Prony recursion."""
    x = dt / tau
    return np.ascontiguousarray(np.exp(-x)), np.ascontiguousarray(-np.expm1(-x) / x)


def _fits(mesh: Mesh, test: CompressionTest) -> bool:
    """Whether the mesh is the test's sample (height, and diameter or equal-area diameter)."""
    if not math.isclose(1e3 * mesh.height_m, test.height_mm, rel_tol=1e-6):
        return False
    radii = [mesh.radius_m] if mesh.cell_type == "quad" else [mesh.radius_m,
                                                               mesh.outer_radius_m]
    return any(math.isclose(2e3 * r, test.diameter_mm, rel_tol=1e-6) for r in radii)


def _twist_pin(mesh: Mesh, sets: dict) -> tuple[int, int]:
    """One (node, direction) that holds the rigid rotation about the axis in static solves.

    A node of the bottom face on the x axis (y = 0, x > 0) keeps y; by symmetry of an
    axisymmetric solution its y reaction is zero, so the pin changes nothing else.
    """
    x, y = mesh.points[:, 0], mesh.points[:, 1]
    tol = 1e-9 * mesh.height_m
    for along, across, direction in ((x, y, 1), (y, x, 0)):
        on = sets["bottom"] & (np.abs(across) <= tol) & (along > tol)
        if on.any():
            return int(np.flatnonzero(on)[0]), direction
    raise ValueError("frictionless or Coulomb platens on a hexahedral mesh need a bottom-face "
                     "node on the x or y axis to hold the rigid rotation of the static set-up "
                     "(use an even n_core / nx, ny)")


#: The volumetric mass's arrays as the time loop takes them: ``held`` (n_nodes, 2) bool, the
#: held DOFs of the current contact set; ``everywhere`` an all-true mask of that shape; the
#: fixed ``coefficient``, ``position``, ``ptr``, ``slot`` of :class:`solver.mass.
#: VolumetricMass`; ``grad_full`` and ``grad`` (n_elem, 4, 2), b_e on every DOF and on the
#: free ones at the last refresh; ``band`` the factor of the free-free Woodbury system;
#: work arrays ``work`` (n_elem,), ``acc``, ``rhs`` (n_nodes, 2), ``b_now`` (n_elem, 4, 2);
#: ``share`` (n_elem, 4) each element's lumped mass per node (kg).
_VolumetricArrays = collections.namedtuple(
    "_VolumetricArrays", "held everywhere coefficient position ptr slot grad_full grad band "
                         "work acc rhs share b_now")


@dataclasses.dataclass(frozen=True)
class _LinearSetup:
    """What an explicit run needs of the linearised problem at unit shear modulus and density.

    It depends on the mesh, the platen condition (bonded or not), the moduli relative to the
    first material's and the mass-scaling options, not on mu or alpha: a calibration's runs
    share it (see :func:`_linear_setup`). Nothing in it is modified by a run.
    """

    ops: object
    sets: dict
    faces: np.ndarray
    fix_tangent: np.ndarray
    twist_pin: np.ndarray
    k_hg_unit: np.ndarray
    node_mass_unit: np.ndarray
    added_mass_fraction: float
    omega2_e: np.ndarray
    omega2_1: float
    w: np.ndarray
    candidate: np.ndarray
    #: volumetric mass (None without): coefficients a_e and the elements' lumped-mass shares
    #: at unit density, and the topology
    coef_unit: np.ndarray | None = None
    share_unit: np.ndarray | None = None
    vm_topology: VolumetricMass | None = None
    probe: TangentProbe | None = None


#: Recently used set-ups, most recent last (see :func:`_linear_setup`), and the lock that
#: keeps threads (the kernels release the GIL) from editing them at once.
_SETUPS: dict = {}
_SETUPS_KEPT = 16
_SETUPS_LOCK = threading.Lock()


def _linear_setup(mesh: Mesh, bonded: bool, shear_inst, shear_lt, bulk, hourglass,
                  mass_scaling, quantile, volumetric_mass) -> _LinearSetup:
    """The linear set-up of a run (:class:`_LinearSetup`), computed once per distinct input.

    ``shear_inst``, ``shear_lt`` and ``bulk`` are per material, over the first material's
    instantaneous shear modulus. The key holds every input by value (the mesh by its
    coordinates, cells and materials).
    """
    key = (mesh.cell_type, mesh.points.tobytes(), mesh.cells.tobytes(),
           mesh.cell_material.tobytes(), bonded, np.asarray(shear_inst).tobytes(),
           np.asarray(shear_lt).tobytes(), np.asarray(bulk).tobytes(), hourglass, mass_scaling,
           quantile, volumetric_mass)
    with _SETUPS_LOCK:
        found = _SETUPS.pop(key, None)
        if found is not None:
            _SETUPS[key] = found
            return found
    found = _compute_linear_setup(mesh, bonded, shear_inst, shear_lt, bulk, hourglass,
                                  mass_scaling, quantile, volumetric_mass)
    with _SETUPS_LOCK:
        while len(_SETUPS) >= _SETUPS_KEPT:
            _SETUPS.pop(next(iter(_SETUPS)))
        _SETUPS[key] = found
    return found


def _compute_linear_setup(mesh, bonded, shear_inst, shear_lt, bulk, hourglass, mass_scaling,
                          quantile, volumetric_mass) -> _LinearSetup:
    """See :func:`_linear_setup`."""
    hexa = mesh.cell_type == "hexahedron"
    if hexa:
        ops = hex_operators(mesh.points, mesh.cells)
    else:
        ops = axisymmetric_operators(mesh.points, mesh.cells)
    mat = mesh.cell_material
    n_nodes, dim = mesh.points.shape
    # --- normalised (unit shear modulus, unit density) linear problem
    shear_inst = np.asarray(shear_inst)[mat]
    shear_lt = np.asarray(shear_lt)[mat]
    bulk = np.asarray(bulk)[mat]
    k_hg_unit = hourglass * shear_lt * ops.gamma_scale
    use_vm = volumetric_mass > 0
    if use_vm:
        # the deviatoric (and hourglass) part alone sets the step; the volumetric part is
        # brought to volumetric_mass times it by the added mass below
        Ke_dev = element_stiffness(ops, shear_inst, np.zeros_like(bulk), k_hg_unit)
        omega2_dev = element_max_frequency_sq(Ke_dev, ops.node_volume)  # unit density
        omega2_e = (1.0 + volumetric_mass) * omega2_dev
    else:
        Ke_inst = element_stiffness(ops, shear_inst, bulk, k_hg_unit)
        omega2_e = element_max_frequency_sq(Ke_inst, ops.node_volume)  # unit density
    if mass_scaling:
        dt_e = 2.0 / np.sqrt(omega2_e)
        target = np.quantile(dt_e, quantile)
        scale_e = np.maximum(1.0, (target / dt_e) ** 2)
    else:
        scale_e = np.ones(len(omega2_e))
    omega2_e = omega2_e / scale_e
    if use_vm:
        omega2_dev = omega2_dev / scale_e
        share_mass = ops.node_volume * scale_e[:, None]  # element's lumped mass per node
        b_ref = np.zeros((mesh.n_cells, 4, 2))
        volumetric_gradient(np.zeros((n_nodes, 2)), mesh.cells, ops.bbar, ops.hbar,
                            np.ones((n_nodes, 2), dtype=np.bool_), np.ones(mesh.n_cells),
                            b_ref)
        kappa = ops.volume * bulk  # volumetric stiffness K V of each element (unit shear)

        # element volumetric frequency^2 against its lumped masses (unit density)
        s_ref = kappa * np.einsum("ead,ea->e", b_ref * b_ref, 1.0 / share_mass)
        beta = np.maximum(0.0, 1.0 / (volumetric_mass * omega2_dev) - 1.0 / s_ref)
        coef_unit = beta * kappa  # a_e at unit density
        omega2_e = element_max_frequency_sq_coupled(
            element_stiffness(ops, shear_inst, bulk, k_hg_unit), share_mass, b_ref, coef_unit)
    node_mass_unit = np.zeros(n_nodes)
    np.add.at(node_mass_unit, mesh.cells, ops.node_volume * scale_e[:, None])
    plain_mass = np.zeros(n_nodes)
    np.add.at(plain_mass, mesh.cells, ops.node_volume)
    added_mass_fraction = float(node_mass_unit.sum() / plain_mass.sum() - 1.0)

    # --- platen constraints: z on both faces; all directions if bonded. The axis of the
    # axisymmetric model holds r. A hexahedral model with sliding faces holds the lateral
    # motion of its axis nodes (exact by symmetry), and its static set-up also the twist.
    sets = mesh.node_sets()
    faces = sets["top"] | sets["bottom"]
    constrained = np.zeros((n_nodes, dim), dtype=bool)
    constrained[faces, -1] = True
    if bonded:
        constrained[faces, :] = True
    if not hexa or not bonded:
        fix_tangent = np.ascontiguousarray(sets["axis"])
        if hexa and not fix_tangent.any():
            raise ValueError("frictionless or Coulomb platens on a hexahedral mesh need nodes "
                             "on the axis (x = y = 0) to hold the rigid lateral motion (use an "
                             "even n_core / nx, ny)")
    else:
        fix_tangent = np.zeros(n_nodes, dtype=bool)
    constrained[fix_tangent, :-1] = True
    static = constrained.copy()
    twist_pin = np.zeros((n_nodes, dim), dtype=bool)
    if hexa and not bonded:
        twist_pin[_twist_pin(mesh, sets)] = True
        static |= twist_pin
    prescribed = np.zeros((n_nodes, dim))
    prescribed[sets["top"], -1] = -1.0  # unit travel of the top platen
    Ke_lt = element_stiffness(ops, shear_lt, bulk, k_hg_unit)
    K_lt = assemble(mesh.cells, Ke_lt, n_nodes, dim)
    free = ~static.ravel()
    lu = factorize(K_lt, free)
    w = influence_field(K_lt, free, prescribed.ravel(), lu=lu)
    mass_unit = np.repeat(node_mass_unit, dim)
    if use_vm:
        # the volumetric mass of the DOFs that move freely at the start (the static free set)
        mass_unit = sp.diags(mass_unit) + added_mass_matrix(
            mesh.cells, b_ref * free.reshape(n_nodes, dim)[mesh.cells], coef_unit, n_nodes)
    omega2_1 = lowest_mode(K_lt, mass_unit, free, load=w, lu=lu)
    del lu
    return _LinearSetup(
        ops=ops, sets=sets, faces=faces, fix_tangent=fix_tangent, twist_pin=twist_pin,
        k_hg_unit=k_hg_unit, node_mass_unit=node_mass_unit,
        added_mass_fraction=added_mass_fraction, omega2_e=omega2_e, omega2_1=float(omega2_1),
        w=w.reshape(n_nodes, dim), candidate=mesh.boundary_nodes(),
        coef_unit=coef_unit if use_vm else None,
        share_unit=share_mass if use_vm else None,
        vm_topology=(VolumetricMass.for_mesh(mesh.cells, n_nodes, np.zeros(mesh.n_cells))
                     if use_vm else None),
        probe=None if hexa else TangentProbe(mesh.cells, n_nodes, dim))



def simulate(
    material: Ogden | Sequence[Ogden],
    test: CompressionTest | None = None,
    mesh: Mesh | None = None,
    *,
    quasi_static_ratio: float | None = None,
    n_out: int = 61,
    hourglass: float = 0.05,
    mass_scaling: bool = True,
    mass_scaling_quantile: float = 0.1,
    dt_safety: float = 0.8,
    parallel: bool = True,
    max_hourglass_ratio: float = 0.1,
    influence: str | None = None,
    influence_updates: int = 10,
    volumetric_mass: float = 1.0,
    mass_refresh_drift: float = 1.1,
    bulk_viscosity: float | None = None,
) -> SimulationResult:
    r"""Run one explicit compression test and return its force-travel curve.

    Parameters
    ----------
    material : Ogden or sequence of Ogden
        The sample's material, or one per material index of the mesh (layers).
    test : CompressionTest, optional
        Geometry, travel, rate and platen condition; the default bonded 30 % test.
    mesh : Mesh, optional
        A mesh of the test's cylinder: axisymmetric quads (default
        :func:`solver.mesh.axisymmetric_cylinder` of the test's size) or hexahedra
        (:func:`solver.mesh.hex_cylinder`, :func:`solver.mesh.hex_block`). Hexahedral meshes
        match the test by height and by diameter or equal-area diameter.
    quasi_static_ratio : float, optional
        Ramp time over the sample's lowest natural period, reached by mass scaling. Default
        :data:`DEFAULT_QUASI_STATIC_RATIO`, or :data:`COULOMB_QUASI_STATIC_RATIO` with
        Coulomb platens: whether a contact node sticks or slips is decided on forces that
        include the sample's (mass-scaled) inertia (with the bulk viscosity, the force at
        friction 0.1-0.3 moved by up to 0.3 % between ratios 10 and 20, by up to 0.7 %
        between 6 and 20, where a rim node lands on the platen).
    n_out : int
        Number of output points along the ramp (>= 2), at equal travel increments: each is
        the state of the step nearest its time (its own time, travel and force are
        recorded), and the step is at most half the smallest output spacing.
    hourglass : float
        Hourglass stiffness coefficient :math:`\kappa` (times the shear modulus).
    mass_scaling : bool
        ``True``: scale the density to reach ``quasi_static_ratio`` (and add mass to the
        smallest elements). ``False``: use the material density and the real ramp time as
        they are (slow for slow ramps).
    mass_scaling_quantile : float
        Elements whose stable step is below this quantile of all elements' steps get extra
        mass to reach it.
    dt_safety : float
        Time step over the stable bound.
    parallel : bool
        Hexahedra only: spread the element loop over numba's threads (race-free, see
        :func:`solver.kernels.hex_forces`); ``False`` runs the serial kernel. The results
        agree to rounding.
    max_hourglass_ratio : float
        The run stops (:class:`SolverInstability`) once the hourglass energy exceeds this
        fraction of the strain energy: the elements then deform in their zero-energy modes
        and the force is an artefact (the usual explicit-dynamics guideline is 10 %).
    influence : {"tangent", "linear"}, optional
        Test field of the virtual-work force. ``"linear"``: the static influence field of the
        undeformed sample, computed once; it removes the inertia from the force to first
        order. ``"tangent"``: the influence field of the current tangent stiffness (coloured
        finite differences of the force kernel, :class:`solver.stiffness.TangentProbe`) with
        the current contact state, recomputed ``influence_updates`` times along the ramp;
        the inertia left in the force is then of second order, so shorter ramps
        (``quasi_static_ratio``) reach the same accuracy. Default: tangent for quads,
        linear for hexahedra (whose sparse solves cost more than they save).
    influence_updates : int
        How often along the ramp the tangent influence field is recomputed.
    volumetric_mass : float
        Volumetric selective mass scaling (:mod:`solver.mass`): inertia is added to each
        element's volumetric deformation until its volumetric frequency is this fraction
        :math:`c` of its deviatoric one, so that the stable step follows the shear waves
        (about 20 times fewer steps at :math:`\nu = 0.499`). Isochoric motions, and with
        them the lowest natural mode and the quasi-static force, keep their inertia. 0 keeps
        lumped masses only. Used by axisymmetric runs with bonded or frictionless platens and
        ``mass_scaling``; hexahedral and Coulomb runs use lumped masses
        (:attr:`SimulationResult.volumetric_mass` says which was used).
    mass_refresh_drift : float
        The volumetric mass is refreshed to the current configuration once an element's
        volumetric frequency against the mass of the last refresh exceeds this factor times
        its design value (:func:`solver.mass.volumetric_drift`: the element's volume gradient
        turns as it deforms, and the turned part meets only lumped masses), and whenever a
        node lands on or leaves a platen.
    bulk_viscosity : float, optional
        Linear bulk viscosity of runs with lumped masses: the fraction of critical damping of
        each element's dilatational mode (:mod:`solver.viscosity`); its work is counted in
        ``damping_J``. Default :data:`solver.viscosity.DEFAULT_BULK_VISCOSITY` with Coulomb
        platens, 0 otherwise. Without it a Coulomb run's stick-slip decisions rectify the
        undamped volumetric ringing into extra slip that changes with the ramp (0.4-3 %
        between ratios 10 and 20 at friction 0.15; at 50 % strain and friction 0.3, 12.0-12.3
        N against 15.9 N with it, which agreed to 0.3 % between ratios 10 and 20 and damping
        0.02-0.3). Not on by default elsewhere: with it, the bonded lumped-mass run (the
        fallback beyond what the volumetric mass reaches) read 6.6 % more force at 70 % and
        inverted an element near 80 %, which it reaches without (not investigated; a suspect
        is the damping growing with the crushed rim elements' volume gradients).

    Returns
    -------
    SimulationResult

    Raises
    ------
    SolverInstability
        If an element inverts, a force becomes NaN or infinite, the kinetic energy blows
        up, or hourglass modes take over (``max_hourglass_ratio``); the message names the
        step, time, travel and element. A run with the volumetric mass that stops is first
        run again with lumped masses (whose step has room to spare); the result's ``notes``
        then say so, and only if that run stops too is the error raised.
    ValueError
        If the mesh does not fit the test, the materials do not cover its layers, or an
        argument is out of range.
    """
    # the keyword arguments as given (first statement: locals() holds only the arguments)
    options = {k: v for k, v in locals().items() if k not in ("material", "test", "mesh")}
    if test is None:
        test = CompressionTest()
    try:
        return _simulate(material, test, mesh, **options)
    except SolverInstability as exc:
        if not _uses_volumetric_mass(mesh, test, mass_scaling, volumetric_mass):
            raise
        # the step follows the deviatoric frequencies, which a collapsing element can outrun
        # between two checks (38 x 10 mm disc at 48 %); the lumped masses' step, set by the
        # pressure waves, has room to spare: run again with them
        options["volumetric_mass"] = 0.0
        result = _simulate(material, test, mesh, **options)
        note = (f"the run with the volumetric mass stopped ({exc}); this is the run with "
                "lumped masses")
        return dataclasses.replace(result, notes=result.notes + (note,))


def _uses_volumetric_mass(mesh, test, mass_scaling, volumetric_mass) -> bool:
    """Whether a run takes the volumetric selective mass (see ``volumetric_mass``).

    Coulomb platens keep lumped masses: a volumetric-mass version of the stick-slip update
    (sticking DOFs held, sliding ones free under the friction limit, one mass matrix) came
    out 2-9 % stiffer than the lumped runs at friction 0.15-1.0, the same at ramp ratios 20,
    40 and 80 (within 0.03 % at friction 0.1 and below). FElupe's static frictional contact
    (``experiments.felupe_reference``, ``platen="coulomb"``) sides with the lumped runs:
    within 0.02 % of them up to 22 % strain at friction 0.15, within 0.6 % up to 20 % at
    friction 1.0 (16 x 16 bilinear cells); so the volumetric-mass version was off.
    """
    return bool(mass_scaling and volumetric_mass > 0
                and (mesh is None or mesh.cell_type == "quad")
                and (test is None or test.platen != "coulomb"))


def _simulate(material, test, mesh, *, quasi_static_ratio, n_out, hourglass, mass_scaling,
              mass_scaling_quantile, dt_safety, parallel, max_hourglass_ratio, influence,
              influence_updates, volumetric_mass, mass_refresh_drift,
              bulk_viscosity) -> SimulationResult:
    """The run of :func:`simulate`: its arguments, defaults resolved there (``test`` given)."""
    if mesh is None:
        mesh = axisymmetric_cylinder(test.diameter_mm, test.height_mm)
    if not _fits(mesh, test):
        raise ValueError(
            f"mesh is {2e3 * mesh.radius_m:.4g} x {1e3 * mesh.height_m:.4g} mm but the test "
            f"sample is {test.diameter_mm:.4g} x {test.height_mm:.4g} mm")
    materials = [material] if isinstance(material, Ogden) else list(material)
    n_mat = int(mesh.cell_material.max()) + 1
    if len(materials) < n_mat:
        raise ValueError(f"mesh has {n_mat} materials (layers) but {len(materials)} given")
    if not n_out >= 2:
        raise ValueError(f"n_out={n_out} must be at least 2")
    if bulk_viscosity is None:
        bulk_viscosity = DEFAULT_BULK_VISCOSITY if test.platen == "coulomb" else 0.0
    if not (math.isfinite(bulk_viscosity) and 0.0 <= bulk_viscosity < 1.0):
        raise ValueError(f"bulk_viscosity={bulk_viscosity!r} must be a fraction of critical "
                         "damping in [0, 1)")
    if quasi_static_ratio is None:
        quasi_static_ratio = (COULOMB_QUASI_STATIC_RATIO if test.platen == "coulomb"
                              else DEFAULT_QUASI_STATIC_RATIO)
    if not quasi_static_ratio > 0:
        raise ValueError(f"quasi_static_ratio={quasi_static_ratio} must be positive")
    if not (np.isfinite(volumetric_mass) and volumetric_mass >= 0):
        raise ValueError(f"volumetric_mass={volumetric_mass} must be a non-negative number")
    if not mass_refresh_drift > 1.0:
        raise ValueError(f"mass_refresh_drift={mass_refresh_drift} must exceed 1")

    hexa = mesh.cell_type == "hexahedron"
    influence = influence or ("linear" if hexa else "tangent")
    if influence not in ("tangent", "linear"):
        raise ValueError(f"influence={influence!r} is not 'tangent' or 'linear'")
    mu, mu_lt, alpha, K, g, tau = _material_tables(materials, n_mat)
    mat = mesh.cell_material
    mu_ref = materials[0].mu0_Pa
    n_nodes, dim = mesh.points.shape
    use_vm = _uses_volumetric_mass(mesh, test, mass_scaling, volumetric_mass)
    lin = _linear_setup(mesh, test.platen == "bonded", mu.sum(axis=1) / mu_ref,
                        mu_lt.sum(axis=1) / mu_ref, K / mu_ref, float(hourglass),
                        bool(mass_scaling), float(mass_scaling_quantile),
                        float(volumetric_mass) if use_vm else 0.0)
    ops, sets, faces, fix_tangent, twist_pin = lin.ops, lin.sets, lin.faces, lin.fix_tangent, \
        lin.twist_pin
    omega2_e, omega2_1, node_mass_unit, w = lin.omega2_e, lin.omega2_1, lin.node_mass_unit, lin.w
    k_hg_unit = lin.k_hg_unit
    bonded = test.platen == "bonded"
    shear_inst = mu.sum(axis=1)[mat] / mu_ref
    shear_lt = mu_lt.sum(axis=1)[mat] / mu_ref

    T = test.ramp_time_s
    if mass_scaling:
        rho_ratio = omega2_1 * (T / (2.0 * np.pi * quasi_static_ratio)) ** 2
    else:
        rho_ratio = materials[0].density_kg_m3 / mu_ref
    density = rho_ratio * mu_ref
    natural_period = 2.0 * np.pi * math.sqrt(rho_ratio / omega2_1)
    # bulk viscosity with lumped masses (see solver.viscosity); it shortens the step
    viscous = not use_vm and bulk_viscosity > 0.0
    step_bv = step_factor(bulk_viscosity) if viscous else 1.0
    dt_stable = 2.0 * step_bv * math.sqrt(rho_ratio / omega2_e.max())
    # every output gets its own step: at most half the smallest output spacing
    times = test.output_times(n_out)
    n_steps_plan = max(1, math.ceil(T / (dt_safety * dt_stable)),
                       math.ceil(2.0 * T / np.diff(times).min()))
    dt = T / n_steps_plan

    # --- physical arrays
    mass = np.ascontiguousarray(density * node_mass_unit)
    if use_vm:
        vm = lin.vm_topology.with_coefficient(density * lin.coef_unit)
    else:  # empty work arrays for the kernel's signature
        vm = VolumetricMass.for_mesh(np.zeros((0, 4), np.int32), 0, np.zeros(0))
    n_vm = mesh.n_cells if use_vm else 0
    vm_arrays = _VolumetricArrays(
        held=np.zeros((n_nodes, dim), dtype=np.bool_),
        everywhere=np.ones((n_nodes, dim), np.bool_), coefficient=vm.coefficient,
        position=vm.position, ptr=vm.ptr, slot=vm.slot, grad_full=vm.gradient,
        grad=np.zeros((n_vm, 4, 2)), band=vm.band, work=vm.work, acc=np.zeros((n_nodes, dim)),
        rhs=np.zeros((n_nodes, dim)),
        share=density * lin.share_unit if use_vm else np.zeros((0, 4)),
        b_now=np.zeros((n_vm, 4, 2)))
    k_hg = np.ascontiguousarray(mu_ref * k_hg_unit)
    share = mu / mu.sum(axis=1, keepdims=True)
    k_ratio = K / mu.sum(axis=1)
    kind, T_ramp, D, t_table, d_table = test.history()
    H = mesh.height_m
    X = mesh.points
    u = np.zeros((n_nodes, dim))
    v = np.ascontiguousarray(test.initial_rate_m_per_s() * w)
    f_int = np.zeros((n_nodes, dim))
    f_c = np.zeros((n_nodes, dim))
    u_eval = np.zeros((n_nodes, dim))
    state = np.zeros(n_nodes, dtype=np.int8)
    state[sets["bottom"]] = BOTTOM
    state[sets["top"]] = TOP
    glued = faces if bonded else np.zeros(n_nodes, dtype=bool)
    candidate = lin.candidate
    anchor = np.zeros((n_nodes, dim))
    n_stress = 6 if hexa else 4  # isochoric PK2 components with a Prony history
    s_prev = np.zeros((mesh.n_cells, n_stress))
    hist = np.zeros((mesh.n_cells, n_stress, g.shape[1]))
    decay, gain = _prony_factors(tau, dt)
    energy_acc = np.zeros(4)
    # during a hold the platen is still: damp the lowest mode critically (dynamic relaxation),
    # which leaves the quasi-static state alone and removes the ring-down of the stop
    hold_damping = 2.0 * math.sqrt(omega2_1 / rho_ratio)
    stiffening = np.zeros(mesh.n_cells)
    mode = _MODE[test.platen]
    friction = float(test.friction)
    va = vm_arrays
    if use_vm and _refresh_mass(u, mesh.cells, ops.bbar, ops.hbar, mass, fix_tangent, state,
                                mode, va.held, va.everywhere, va.coefficient, va.position,
                                va.ptr, va.slot, va.grad_full, va.grad, va.band, True) >= 0:
        raise SolverInstability("the volumetric mass matrix is not positive definite", 0, 0.0,
                                0.0)

    momentum = np.zeros((n_nodes, dim))
    c_bv = (bulk_viscosity_coefficient(K[mat], ops.volume, np.sqrt(omega2_e / rho_ratio),
                                       float(bulk_viscosity)) if viscous else np.zeros(0))
    grad_bv = np.zeros((len(c_bv),) + ops.bbar.shape[1:])
    f_v = np.zeros((n_nodes, dim))  # bulk-viscous forces (zero without bulk viscosity)

    def kinetic(vel) -> float:
        """Kinetic energy (J) with the mass of the last refresh."""
        if not use_vm:
            return 0.5 * float(np.einsum("n,na,na->", mass, vel, vel))
        apply_mass(vel, mesh.cells, mass, vm.gradient, vm.coefficient, momentum)
        return 0.5 * float(np.vdot(vel, momentum))

    kinetic0 = kinetic(v)
    if hexa:
        ptr, slot = node_slots(mesh.cells, n_nodes)
        fe = np.zeros((mesh.n_cells, 8, 3))
        status_e = np.zeros(mesh.n_cells, dtype=np.int32)
        fe1 = np.zeros((8, 3))
        energy_fn = hex_energy
        energy_args = (mesh.cells, ops.bbar, ops.volume, ops.gamma, k_hg, mat, mu_lt, alpha, K)
    else:
        energy_fn = axisym_energy
        energy_args = (mesh.cells, ops.bbar, ops.hbar, ops.volume, ops.gamma, k_hg, mat, mu_lt,
                       alpha, K)

    def advance(t_stop, t, dt, dt_prev, decay, gain):
        common = (t_stop, t, dt, dt_prev, kind, T_ramp, D, t_table, d_table, H, hold_damping,
                  u, v, f_int, f_c, mass, X, fix_tangent, state, glued, candidate, anchor,
                  mode, friction)
        if hexa:
            return _advance_hex(*common, mesh.cells, ops.bbar, ops.volume, ops.gamma, k_hg,
                                mat, mu, alpha, K, g, decay, gain, s_prev, hist, ptr, slot, fe,
                                status_e, fe1, bool(parallel), u_eval, energy_acc, c_bv,
                                grad_bv, f_v)
        return _advance_axisym(*common, mesh.cells, ops.bbar, ops.hbar, ops.volume, ops.gamma,
                               k_hg, mat, mu, alpha, K, g, decay, gain, s_prev, hist, u_eval,
                               energy_acc, use_vm, vm_arrays, float(mass_refresh_drift),
                               c_bv, grad_bv, f_v)

    def forces(uu):
        """Internal forces at ``uu`` without advancing any history (for the tangent)."""
        ff = np.zeros_like(uu)
        if hexa:
            hex_forces_serial(uu, mesh.cells, ops.bbar, ops.volume, ops.gamma, k_hg, mat, mu,
                              alpha, K, g, decay, gain, s_prev, hist, False, fe1, ff)
        else:
            axisym_forces(uu, mesh.cells, ops.bbar, ops.hbar, ops.volume, ops.gamma, k_hg, mat,
                          mu, alpha, K, g, decay, gain, s_prev, hist, False, ff)
        return ff

    probe = None
    if influence == "tangent":
        probe = lin.probe or TangentProbe(mesh.cells, n_nodes, dim)

    def tangent_influence():
        """Influence field of the current tangent stiffness and contact state."""
        Kt = probe.stiffness(forces, u_eval, 1e-7 * H)
        held = twist_pin.copy()
        held[fix_tangent, :-1] = True
        touching = state != FREE
        held[touching, -1] = True
        if mode != FRICTIONLESS:
            held[touching, :-1] = True
        held[glued, :] = True
        moved = np.zeros((n_nodes, dim))
        moved[state == TOP, -1] = -1.0
        return influence_field(Kt, ~held.ravel(), moved.ravel(),
                               banded=True).reshape(n_nodes, dim)

    def stiffen():
        if hexa:
            hex_stiffening(u, mesh.cells, ops.bbar, mat, alpha, share, k_ratio, stiffening)
        else:
            axisym_stiffening(u, mesh.cells, ops.bbar, ops.hbar, mat, alpha, share, k_ratio,
                              stiffening)

    out = {k: np.zeros(len(times)) for k in ("time_s", "d", "force", "reaction", "bottom",
                                          "external_J", "internal_J", "strain_J",
                                          "hourglass_J", "kinetic_J", "friction_J", "damping_J",
                                          "radius")}
    if use_vm:
        # the element bound of the highest frequency grows with the material's tangent and
        # the elements' shape, but the mesh's highest mode is set by the volumetric-
        # deviatoric balance of the small rim elements and moves much less (default test:
        # +5 % at 30 %, where a scalar bound of the tangent grew 16-fold; alpha 12: 7.8-fold):
        # it is followed by Lanczos on the tangent (forward differences of the force kernel)
        # and the current mass, at the start and as often as its growth asks (below)
        check = {"next": 0, "k": 0, "value": 0.0}
        held, grad_free, band, work = va.held, va.grad, va.band, va.work
        # the forces of the tangent see the long-term deviatoric moduli (no history update)
        visco = float(np.max(shear_inst / shear_lt))
        ritz = [np.random.default_rng(0).uniform(0.5, 1.5, (n_nodes, dim))]

        def mass_times(x):
            out_m = np.empty_like(x)
            apply_mass(x, mesh.cells, mass, grad_free, vm.coefficient, out_m)
            return out_m

        def mass_inverse(x):
            out_m = np.zeros_like(x)
            apply_inverse(x, mesh.cells, mass, grad_free, vm.position, band, work, out_m)
            return out_m * ~held

        def highest_frequency_sq():
            f0 = forces(u_eval)

            def stiffness_times(x):
                h = 1e-7 * H / max(np.abs(x).max(), 1e-300)
                return (forces(u_eval + h * x) - f0) / h * ~held

            value, vector = lanczos_max(stiffness_times, mass_times, mass_inverse,
                                        ritz[0] * ~held)
            ritz[0] = vector
            return visco * value

    t = 0.0
    dt_prev = 0.0
    steps = 0
    start = time.perf_counter()
    every = max(1, (len(times) - 1) // max(1, influence_updates))
    w_contact = state != FREE  # the contact set of the influence field ``w``
    for k, t_stop in enumerate(times):
        status, elem, t_eval, t, dt_prev, n = advance(t_stop, t, dt, dt_prev, decay, gain)
        steps += n
        if status != OK:
            reason = {INVERTED: "inverted element (J <= 0)",
                      NOT_FINITE: "non-finite stress (NaN or inf)",
                      MASS_NOT_DEFINITE: "the volumetric mass matrix is no longer positive "
                                         "definite (a deformed element's volume gradient "
                                         "is not finite)"}[status]
            d_mm = 1e3 * travel(t_eval, kind, T_ramp, D, t_table, d_table)
            raise SolverInstability(reason, steps, t_eval, d_mm, elem)
        d = travel(t_eval, kind, T_ramp, D, t_table, d_table)
        # the field belongs to a contact set: where a node landed on (or left) a platen since
        # it was computed, it is computed again (else the inertia of the landing's ringing
        # stays in the force: a 29.9 x 15.1 mm Coulomb solve swung to -2.4 times its force)
        if probe is not None and k > 0 and ((k - 1) % every == 0
                                            or not np.array_equal(state != FREE, w_contact)):
            w = tangent_influence()
            w_contact = state != FREE
        _record(out, k, t_eval, d, u_eval, v, f_int, f_c, state, w, kinetic(v), energy_acc,
                X, energy_fn, energy_args, 0.5 * dt_prev, mode == COULOMB)
        kinetic_now, external = out["kinetic_J"][k], out["external_J"][k]
        if not np.isfinite(u).all() or not np.isfinite(kinetic_now):
            raise SolverInstability("non-finite displacement or kinetic energy", steps, t_eval,
                                    1e3 * d, int(np.argmax(~np.isfinite(u).all(axis=1))))
        if kinetic_now > 10.0 * (abs(external) + kinetic0) and kinetic_now > 0.0:
            node = int(np.argmax(np.einsum("na,na->n", v, v) * mass))
            elem = int(np.flatnonzero((mesh.cells == node).any(axis=1))[0])
            raise SolverInstability(
                f"energy blow-up: kinetic energy {kinetic_now:.3g} J exceeds ten times the platen "
                f"work plus the initial kinetic energy, {abs(external) + kinetic0:.3g} J "
                f"(fastest node {node})", steps, t_eval, 1e3 * d, elem)
        strain, hourglass_energy = out["strain_J"][k], out["hourglass_J"][k]
        if strain > 0.0 and hourglass_energy > max_hourglass_ratio * strain:
            per_element = _hourglass_energy(u_eval, mesh.cells, ops.gamma, k_hg)
            raise SolverInstability(
                f"hourglassing: the hourglass energy is {hourglass_energy / strain:.1%} of the "
                f"strain energy (limit {max_hourglass_ratio:.0%}); elements deform in their "
                f"zero-energy modes and the force is no longer trustworthy; largest hourglass "
                f"energy", steps, t_eval, 1e3 * d, int(np.argmax(per_element)))
        # re-check the stable step as elements shorten and the material stiffens
        if use_vm:
            # the start is covered by the element bound, the last point has no ramp left
            if k < check["next"] or k == len(times) - 1:
                continue
            value = highest_frequency_sq()
            # the growth per output since the last check, extrapolated over the next interval,
            # chosen so that the predicted growth stays below 20 % (at most a fifth of the
            # ramp); 10 % on top for Lanczos, which finds the highest frequency from below
            # (its warm-started estimates scatter by a few per cent)
            rate = 1.0
            if k > check["k"] and check["value"] > 0.0:
                rate = max(1.0, (value / check["value"]) ** (1.0 / (k - check["k"])))
            longest = max(1, (len(times) - 1) // _STEP_CHECKS)
            interval = longest if rate <= 1.0 else int(
                min(longest, max(1, math.log(1.2) / math.log(rate))))
            check.update(next=k + interval, k=k, value=value)
            dt_now = dt_safety * 2.0 / math.sqrt(1.1 * value * rate ** interval)
        else:
            stiffen()
            dt_now = dt_safety * 2.0 * step_bv * math.sqrt(
                rho_ratio / np.max(omega2_e * stiffening))
        if dt > dt_now and t < T:
            remaining = T - t
            dt = remaining / math.ceil(remaining / dt_now)
            decay, gain = _prony_factors(tau, dt)
    wall = time.perf_counter() - start

    # Cauchy stress of the final state (the Prony history belongs to it)
    cell_stress = np.zeros((mesh.n_cells, 6))
    if hexa:
        hex_stress(u_eval, mesh.cells, ops.bbar, mat, mu, alpha, K, g, decay, gain, s_prev,
                   hist, cell_stress)
    else:
        axisym_stress(u_eval, mesh.cells, ops.bbar, ops.hbar, mat, mu, alpha, K, g, decay,
                      gain, s_prev, hist, cell_stress)

    energy = {key: out[key] for key in ("external_J", "internal_J", "strain_J", "hourglass_J",
                                        "kinetic_J", "friction_J", "damping_J")}
    return SimulationResult(
        time_s=out["time_s"], displacement_mm=1e3 * out["d"], force_N=out["force"],
        reaction_N=out["reaction"], bottom_reaction_N=out["bottom"], energy=energy,
        contact_radius_mm=1e3 * out["radius"], mesh=mesh, displacement_m=u_eval.copy(),
        n_steps=steps, dt_s=T / n_steps_plan, natural_period_s=natural_period,
        quasi_static_ratio=T / natural_period, density_kg_m3=density,
        added_mass_fraction=lin.added_mass_fraction, wall_s=wall, cell_stress_Pa=cell_stress,
        volumetric_mass=use_vm)


def _hourglass_energy(u, cells, gamma, k_hg):
    """Hourglass energy of every element (J), shape (n_cells,)."""
    if gamma.ndim == 2:  # quad: one mode per direction
        q = np.einsum("ei,eia->ea", gamma, u[cells])
    else:  # hexahedron: four modes per direction
        q = np.einsum("eki,eia->eka", gamma, u[cells]).reshape(len(cells), -1)
    return 0.5 * k_hg * np.einsum("ea,ea->e", q, q)


def _record(out, k, t_eval, d, u, v, f_int, f_c, state, w, kinetic, energy_acc, X, energy_fn,
            energy_args, half_step, friction):
    r"""Store output point ``k``: forces by virtual work and reaction, energies, contact.

    The work accumulators hold :math:`\sum f^n \cdot (u^{n+1/2} - u^{n-1/2})` up to the last
    step, half a step beyond the state :math:`u^n` of the forces and the stored energy; the
    work of that half step, :math:`f^n \cdot v^{n+1/2}\,\Delta t/2` (``half_step`` is
    :math:`\Delta t/2`), is taken off so that the works belong to the same time as the
    stored energy (an offset of order :math:`\Delta t`, 3e-3 of the final work at the
    volumetric mass's step, otherwise). The damping work of a hold is left as accumulated.
    """
    top = state == TOP
    bottom = state == BOTTOM
    contact = top | bottom
    wk = w.copy()
    wk[top, -1] = -1.0
    wk[bottom, -1] = 0.0
    tangential = np.einsum("na,na->", f_c[contact, :-1], wk[contact, :-1])
    out["time_s"][k] = t_eval
    out["d"][k] = d
    out["force"][k] = np.einsum("na,na->", f_int, wk) - tangential
    out["reaction"][k] = -f_c[top, -1].sum()
    out["bottom"][k] = f_c[bottom, -1].sum()
    strain, hourglass = energy_fn(u, *energy_args)
    out["strain_J"][k] = strain
    out["hourglass_J"][k] = hourglass
    out["kinetic_J"][k] = kinetic
    out["internal_J"][k] = energy_acc[0] - half_step * np.einsum("na,na->", f_int, v)
    out["external_J"][k] = energy_acc[1] - half_step * np.einsum("na,na->", f_c, v)
    out["friction_J"][k] = energy_acc[2] - (half_step * np.einsum(
        "na,na->", f_c[contact, :-1], v[contact, :-1]) if friction else 0.0)
    out["damping_J"][k] = energy_acc[3]
    # contact radius: distance of the outermost top-contact node from the axis
    lateral = X[top, :-1] + u[top, :-1]
    out["radius"][k] = np.sqrt((lateral**2).sum(axis=1)).max() if top.any() else 0.0
