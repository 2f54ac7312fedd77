"""An independent direct-collocation solve of the planar-step problem (CasADi + IPOPT, Hermite-Simpson).

Written from the problem's statement (``docs/gait-problem.md``) alone, sharing only the robot parameters
(``biped_jax.robots.specs``) with the product: its own coordinates (absolute link pitches from the
vertical, positive leaning forward), its own Lagrangian dynamics (CasADi symbolic), its own impact map
and relabelling. Hermite-Simpson in separated form: states and torques at every knot and segment
midpoint, every path constraint at all of them, J by Simpson's rule.

Coordinates: phi = (shank1, thigh1, torso, thigh2, shank2), each link's pitch of its "up" direction
(foot to knee, knee to hip, hip to torso top). Stance foot at the origin. Knee flexion
k1 = phi_shank1 - phi_thigh1, k2 = phi_shank2 - phi_thigh2 (>= 0: the knee ahead of its hip-foot line).
Joint rates for the power limit: hip i = torso - thigh i, knee i as above (the torques' signs do not
enter J or |qdot u|).

Needs the ``bench`` extra (casadi).
"""

from __future__ import annotations

import dataclasses
import time

import casadi as ca
import numpy as np

from biped_jax.robots.specs import PLANAR_SPECS, PlanarBipedSpec

# relative joint angles (H1, K1, H2, K2) = S phi
RELATIVE_JOINTS = np.array([[0, -1, 1, 0, 0], [1, -1, 0, 0, 0], [0, 0, 1, -1, 0], [0, 0, 0, -1, 1]], dtype=float)
# the product's joints (H1, K1, H2, K2) = RELATIVE_JOINTS @ phi times these: its hips turn about -y where the
# peer's are torso - thigh (for the scripts that carry gaits between the two)
JOINT_SIGNS = np.array([-1.0, 1.0, -1.0, 1.0])
_RELABEL = [4, 3, 2, 1, 0]


def _up(phi):
    return ca.vertcat(ca.sin(phi), ca.cos(phi))


@dataclasses.dataclass(frozen=True)
class PeerProblem:
    spec: PlanarBipedSpec
    speed: float
    power_limit: float
    step_length: float = 0.2
    friction: float = 0.8
    torque_bound: float = 20.0
    knee_max: float = 2.6


def _points(spec: PlanarBipedSpec, hip, phi):
    """Joint positions and centres of mass given the hip position and the five pitches."""
    ls, lt = spec.shank_length, spec.thigh_length
    knee1 = hip - lt * _up(phi[1])
    foot1 = knee1 - ls * _up(phi[0])
    knee2 = hip - lt * _up(phi[3])
    foot2 = knee2 - ls * _up(phi[4])
    coms = [knee1 - spec.link_com("shank") * _up(phi[0]),
            hip - spec.link_com("thigh") * _up(phi[1]),
            hip + spec.link_com("torso") * _up(phi[2]),
            hip - spec.link_com("thigh") * _up(phi[3]),
            knee2 - spec.link_com("shank") * _up(phi[4])]
    return dict(knee1=knee1, foot1=foot1, knee2=knee2, foot2=foot2, coms=coms)


def _model(spec: PlanarBipedSpec):
    """CasADi functions of the pinned (single support) and floating (impact) dynamics."""
    masses = [spec.shank_mass, spec.thigh_mass, spec.torso_mass, spec.thigh_mass, spec.shank_mass]
    inertias = [spec.link_inertia(k)[1] for k in ("shank", "thigh", "torso", "thigh", "shank")]
    g = spec.gravity
    phi, phid = ca.SX.sym("phi", 5), ca.SX.sym("phid", 5)
    hip_f, hipd_f = ca.SX.sym("hip", 2), ca.SX.sym("hipd", 2)

    def energies(hip, hipd, phi, phid, coordinates, rates):
        pts = _points(spec, hip, phi)
        kinetic, potential = 0, 0
        for m, inertia, com, rate in zip(masses, inertias, pts["coms"], ca.vertsplit(phid)):
            v = ca.jtimes(com, coordinates, rates)
            kinetic += 0.5 * m * ca.dot(v, v) + 0.5 * inertia * rate**2
            potential += m * g * com[1]
        return kinetic, potential, pts

    # pinned: the hip follows from the stance foot at the origin
    hip_p = spec.thigh_length * _up(phi[1]) + spec.shank_length * _up(phi[0])
    hipd_p = ca.jtimes(hip_p, phi, phid)
    kinetic, potential, pts = energies(hip_p, hipd_p, phi, phid, phi, phid)
    mass = ca.hessian(kinetic, phid)[0]
    momentum = ca.gradient(kinetic, phid)
    bias = ca.jtimes(momentum, phi, phid) - ca.gradient(kinetic, phi) + ca.gradient(potential, phi)
    u = ca.SX.sym("u", 4)
    phidd = ca.solve(mass, RELATIVE_JOINTS.T @ u - bias)
    total = sum(masses)
    com = sum(m * c for m, c in zip(masses, pts["coms"])) / total
    com_acc = ca.jtimes(ca.jtimes(com, phi, phid), phi, phid) + ca.jtimes(com, phi, phidd)
    force = total * (com_acc + ca.vertcat(0, g))
    foot2 = pts["foot2"]
    outputs = ca.Function("outputs", [phi, phid, u], [phidd, force, foot2, ca.jtimes(foot2, phi, phid),
                                                       hip_p[1], pts["knee1"][1], pts["knee2"][1]])
    # floating: hip free, for the impact map
    z, zd = ca.vertcat(hip_f, phi), ca.vertcat(hipd_f, phid)
    kinetic_f, _, pts_f = energies(hip_f, hipd_f, phi, phid, z, zd)
    mass_f = ca.hessian(kinetic_f, zd)[0]
    jac2, jac1 = ca.jacobian(pts_f["foot2"], z), ca.jacobian(pts_f["foot1"], z)
    kkt = ca.blockcat([[mass_f, -jac2.T], [jac2, ca.SX.zeros(2, 2)]])
    solution = ca.solve(kkt, ca.vertcat(mass_f @ zd, ca.SX.zeros(2)))
    zd_after = solution[:7]
    impact_f = ca.Function("impact_f", [hip_f, hipd_f, phi, phid], [zd_after[2:], solution[7:], jac1 @ zd_after])
    hip_fn = ca.Function("hip", [phi, phid], [hip_p, hipd_p])
    return outputs, impact_f, hip_fn


def solve(problem: PeerProblem, segments: int = 60, guess: dict | None = None, print_level: int = 0,
          minimise_power_limit: bool = False, power_points: int = 0) -> dict:
    """Hermite-Simpson transcription with ``segments`` segments; returns J, status, the solution.

    ``power_points``: the power limit held also at this many evenly spaced points inside every interval
    between two nodes, on the interpolants of :func:`power_between_nodes` (the rates' cubic Hermite, the
    torques' quadratic): a limit held between the nodes, as a motor must, not at the nodes alone.

    ``minimise_power_limit``: the power limit becomes a variable (started at ``problem.power_limit``)
    and the objective; the result's "power_limit" is the smallest limit with a gait of this mesh,
    "cost" that gait's J."""
    started = time.perf_counter()
    spec = problem.spec
    outputs, impact, hip_fn = _model(spec)
    t_f = problem.step_length / problem.speed
    h = t_f / segments
    nodes = 2 * segments + 1  # knots and midpoints
    opti = ca.Opti()
    phi = opti.variable(5, nodes)
    phid = opti.variable(5, nodes)
    u = opti.variable(4, nodes)
    limit = opti.variable() if minimise_power_limit else problem.power_limit
    f = []
    for k in range(nodes):
        phidd, force, foot, foot_v, hip_z, knee1_z, knee2_z = outputs(phi[:, k], phid[:, k], u[:, k])
        f.append(ca.vertcat(phid[:, k], phidd))
        rates = RELATIVE_JOINTS @ phid[:, k]
        power = rates * u[:, k]
        opti.subject_to(opti.bounded(-limit, power, limit))
        opti.subject_to(opti.bounded(-problem.torque_bound, u[:, k], problem.torque_bound))
        opti.subject_to(force[1] >= 0)
        opti.subject_to(opti.bounded(-problem.friction * force[1], force[0], problem.friction * force[1]))
        opti.subject_to(ca.vertcat(hip_z, knee1_z, knee2_z) >= 0)
        for knee in (phi[0, k] - phi[1, k], phi[4, k] - phi[3, k]):
            opti.subject_to(opti.bounded(0, knee, problem.knee_max))
        if 0 < k < nodes - 1:
            opti.subject_to(foot[1] >= 0)
        if k == nodes - 1:
            opti.subject_to(foot[0] == problem.step_length)
            opti.subject_to(foot[1] == 0)
            opti.subject_to(foot_v[1] <= 0)
    for a in range(nodes - 1):
        for j in range(1, power_points + 1):
            rates, torque = interpolated(a, j / (power_points + 1), lambda k: RELATIVE_JOINTS @ phid[:, k],
                                         lambda k: RELATIVE_JOINTS @ f[k][5:], lambda k: u[:, k], h / 2)
            opti.subject_to(opti.bounded(-limit, rates * torque, limit))
    x = ca.vertcat(phi, phid)
    cost = 0
    for s in range(segments):
        a, m, b = 2 * s, 2 * s + 1, 2 * s + 2
        opti.subject_to(x[:, m] == 0.5 * (x[:, a] + x[:, b]) + h / 8 * (f[a] - f[b]))
        opti.subject_to(x[:, b] - x[:, a] == h / 6 * (f[a] + 4 * f[m] + f[b]))
        cost += h / 6 * (ca.sumsqr(u[:, a]) + 4 * ca.sumsqr(u[:, m]) + ca.sumsqr(u[:, b]))
    # impact at t_f, relabelling, periodicity
    hip, hipd = hip_fn(phi[:, -1], phid[:, -1])
    phid_after, impulse, old_foot_v = impact(hip, hipd, phi[:, -1], phid[:, -1])
    opti.subject_to(phi[:, 0] == phi[_RELABEL, -1])
    opti.subject_to(phid[:, 0] == phid_after[_RELABEL])
    opti.subject_to(impulse[1] >= 0)
    opti.subject_to(opti.bounded(-problem.friction * impulse[1], impulse[0], problem.friction * impulse[1]))
    opti.subject_to(old_foot_v[1] >= 0)
    if minimise_power_limit:
        opti.subject_to(limit >= 0)
        opti.set_initial(limit, problem.power_limit)
        opti.minimize(limit)
    else:
        opti.minimize(cost)
    # a heuristic start of the peer's own: straight legs mirrored, torso upright, swing knee flexed
    if guess is None:
        s = np.linspace(0, 1, nodes)
        half = np.arcsin(0.5 * problem.step_length / spec.leg_length)
        start = np.array([half, half, 0.0, -half, -half])
        guess_phi = start[:, None] + (start[_RELABEL] - start)[:, None] * s[None]
        guess_phi[4] += 0.8 * np.sin(np.pi * s)
        guess_phi[3] += 0.3 * np.sin(np.pi * s)
        guess = {"phi": guess_phi, "phid": np.gradient(guess_phi, s * t_f, axis=1), "u": np.zeros((4, nodes))}
    opti.set_initial(phi, guess["phi"])
    opti.set_initial(phid, guess["phid"])
    opti.set_initial(u, guess["u"])
    opti.solver("ipopt", {"print_time": False}, {"print_level": print_level, "max_iter": 3000, "tol": 1e-8})
    try:
        result = opti.solve()
        status = "converged"
        value = result.value
    except RuntimeError:
        status = opti.stats()["return_status"]
        value = opti.debug.value
    stats = opti.stats()
    return {"cost": float(value(cost)), "power_limit": float(value(limit)), "status": status,
            "ipopt_status": stats["return_status"],
            "iterations": int(stats["iter_count"]), "segments": segments, "wall_time_s": time.perf_counter() - started,
            "phi": np.asarray(value(phi)), "phid": np.asarray(value(phid)), "u": np.asarray(value(u)),
            "t": np.linspace(0, t_f, nodes)}


def hermite_weights(tau):
    """The cubic Hermite basis at ``tau`` in [0, 1] of an interval: the weights of its start's value, start's
    slope times the width, end's value, end's slope times the width."""
    return 2 * tau**3 - 3 * tau**2 + 1, tau**3 - 2 * tau**2 + tau, -2 * tau**3 + 3 * tau**2, tau**3 - tau**2


def quadratic_weights(sigma):
    """The weights of the quadratic through a segment's first knot, midpoint and last knot at ``sigma`` in
    [0, 1] of the segment (Lagrange basis)."""
    return (2 * sigma - 1) * (sigma - 1), 4 * sigma * (1 - sigma), sigma * (2 * sigma - 1)


def interpolated(a, tau, rate, slope, torque, width):
    """The joint rates and torques at ``tau`` in [0, 1] of the interval between nodes ``a`` and ``a + 1``
    (``width`` s apart) on the transcription's own interpolants: the rates' cubic Hermite (their slopes the
    dynamics' accelerations at the nodes), the torques' quadratic through the segment's three nodes.
    ``rate``, ``slope``, ``torque``: node index -> that node's values (CasADi or numpy alike)."""
    h00, h10, h01, h11 = hermite_weights(tau)
    rates = h00 * rate(a) + h10 * width * slope(a) + h01 * rate(a + 1) + h11 * width * slope(a + 1)
    segment = a - a % 2  # the segment's first knot
    w0, w1, w2 = quadratic_weights(0.5 * (a - segment + tau))
    return rates, w0 * torque(segment) + w1 * torque(segment + 1) + w2 * torque(segment + 2)


def power_between_nodes(problem: PeerProblem, result: dict, samples: int = 20) -> float:
    """The largest joint power |(S phid) u| of a solve's gait between its nodes, W, on :func:`interpolated`
    (the transcription's own interpolants), ``samples`` points per node interval. The limit holds at the
    nodes (and at ``power_points`` between them); this is what the gait asks of a motor anywhere."""
    outputs = _model(problem.spec)[0]
    phi, phid, u, t = result["phi"], result["phid"], result["u"], result["t"]
    phidd = np.stack([np.asarray(outputs(phi[:, k], phid[:, k], u[:, k])[0]).ravel() for k in range(phi.shape[1])],
                     axis=1)
    rates, slopes = RELATIVE_JOINTS @ phid, RELATIVE_JOINTS @ phidd
    tau = np.arange(samples) / samples
    largest = float(np.abs(rates[:, -1] * u[:, -1]).max())
    for a in range(len(t) - 1):
        r, torques = interpolated(a, tau, lambda k: rates[:, k, None], lambda k: slopes[:, k, None],
                                  lambda k: u[:, k, None], t[a + 1] - t[a])
        largest = max(largest, float(np.abs(r * torques).max()))
    return largest


def main():
    import argparse
    from pathlib import Path

    from _results import save_results
    parser = argparse.ArgumentParser(description="direct-collocation peer solve of one planar-step model")
    parser.add_argument("--mass-class", default="12kg", choices=("12kg", "18kg"))
    parser.add_argument("--speed", type=float, default=0.555, help="m/s")
    parser.add_argument("--power-limit", type=float, default=20.0, help="W")
    parser.add_argument("--segments", type=int, default=60)
    parser.add_argument("--minimise-power-limit", action="store_true",
                        help="solve at --power-limit, then minimise the limit from that gait (the smallest M_W)")
    parser.add_argument("--name", default="collocation_peer")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args()
    problem = PeerProblem(PLANAR_SPECS[args.mass_class], args.speed, args.power_limit)
    result = solve(problem, args.segments)
    print(f"{args.mass_class} {args.speed} m/s {args.power_limit} W: {result['status']} ({result['ipopt_status']}), "
          f"J = {result['cost']:.4f} on {args.segments} segments, {result['iterations']} iterations, "
          f"{result['wall_time_s']:.1f} s")
    if args.minimise_power_limit:
        result = solve(problem, args.segments, guess=result, minimise_power_limit=True)
        print(f"smallest power limit: {result['power_limit']:.4f} W ({result['status']}), J = {result['cost']:.4f} "
              f"there, {result['wall_time_s']:.1f} s")
    row = {k: v for k, v in result.items() if not isinstance(v, np.ndarray)}
    arrays = {k: v.tolist() for k, v in result.items() if isinstance(v, np.ndarray)}
    save_results(f"{args.name}_{args.mass_class}_{args.speed}_{args.power_limit:g}W",
                 vars(args) | {"out": str(args.out)}, [row | {"solution": arrays}], args.out)


if __name__ == "__main__":
    main()
