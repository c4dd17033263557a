"""Single-core LIGGGHTS 3.8 reference run of a granular pour (numpy only).

Writes a LIGGGHTS input deck plus a LAMMPS data file with the given grain
centres, runs the Debian ``liggghts`` binary on ONE process (no mpirun,
OMP_NUM_THREADS=1), and parses the log: loop wall time, particle-steps per
second, final max z and the number of atoms left.

Contact model (identical for particle-particle and particle-wall, wall =
same material, atom type 1):

    pair_style gran model hertz tangential history      (defaults:
        tangential_damping on, limitForce off)

    Y* = 1/((1-nu_i^2)/E_i + (1-nu_j^2)/E_j)             (= E/(2(1-nu^2)))
    G* = 1/(2(2-nu_i)(1+nu_i)/E_i + 2(2-nu_j)(1+nu_j)/E_j)  (= E/(4(2-nu)(1+nu)))
    R* = RiRj/(Ri+Rj)  (wall: R* = Ri, also for the concave cylinder)
    m* = mimj/(mi+mj)  (wall: m* = mi)
    Sn = 2 Y* sqrt(R* dn),  St = 8 G* sqrt(R* dn)
    kn = 4/3 Y* sqrt(R* dn),  kt = St
    beta = ln(e)/sqrt(ln(e)^2 + pi^2)
    gamma_n = -2 sqrt(5/6) beta sqrt(Sn m*),  gamma_t = -2 sqrt(5/6) beta sqrt(St m*)
    Fn = kn dn - gamma_n vn        (no clamp: may be slightly attractive)
    shear += v_t,rel dt ; shear projected onto the tangent plane every step
    Ft = -kt shear - gamma_t v_t,rel   if |kt shear| <= mu |Fn|
    else Ft = -mu|Fn| shear/|shear| and shear := Ft/(-kt)  (no damping term)
    torque lever arm = R - dn/2.

``pour_bed`` pours and settles a random bed (cached by its parameters): the
common start of the fair fbed / LIGGGHTS benchmark, benchmarks/dem_throughput.py.

Run ``python benchmarks/liggghts/liggghts_pour.py --n 10000`` for the
benchmark table.  See README.md next to this file.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import signal
import subprocess
import tempfile
import time

import numpy as np

_BINARY_NAMES = ("liggghts", "lmp_auto", "lmp_serial", "lmp_mpi", "lmp")


def find_binary() -> str | None:
    """Path of the LIGGGHTS executable ($LIGGGHTS_BIN overrides), or None."""
    env = os.environ.get("LIGGGHTS_BIN")
    if env:
        return env if (os.path.isfile(env) and os.access(env, os.X_OK)) else None
    for name in _BINARY_NAMES:
        path = shutil.which(name)
        if path:
            return path
    return None


def available() -> bool:
    """True when a LIGGGHTS binary is on PATH (prints nothing)."""
    return find_binary() is not None


# --------------------------------------------------------------------------
# initial condition helper (so fbed can start from the very same lattice)
# --------------------------------------------------------------------------

def make_lattice(n: int, diameter: float = 2e-3, spacing: float = 1.05,
                 cylinder_radius: float | None = None,
                 cylinder_center=(0.0, 0.0), floor_z: float = 0.0,
                 jitter: float = 0.0, seed: int = 0):
    """Simple-cubic lattice of ``n`` non-overlapping grains inside a z-cylinder.

    Lattice pitch s = spacing*diameter; every grain keeps a gap of
    (s-d)/2 to the side wall and the floor.  If ``cylinder_radius`` is None it
    is chosen so the column is about as tall as it is wide (H ~ 2R).
    Layers are filled from the floor up; inside a layer the grains closest to
    the axis come first (so a partial top layer is centred).
    ``jitter`` > 0 shifts every grain in x and y by U(-jitter, jitter)*diameter
    (numpy default_rng(seed)) to break the perfect stacking; it must stay below
    (spacing-1)/2 so the lattice stays non-overlapping.
    Returns (positions (n,3) float64, cylinder_radius).
    """
    n = int(n)
    if n <= 0:
        raise ValueError("n must be positive")
    d = float(diameter)
    s = spacing * d
    if s < d:
        raise ValueError("spacing must be >= 1 (non-overlapping lattice)")
    gap = 0.5 * (s - d)
    if jitter < 0.0 or (jitter > 0.0 and jitter * d >= gap):
        raise ValueError("jitter must be in [0, (spacing-1)/2)")
    jit = jitter * d
    if cylinder_radius is None:
        # n ~ (2R/s) * pi R^2 / s^2  ->  R ~ s (n / 2 pi)^(1/3)
        cylinder_radius = s * (n / (2.0 * math.pi)) ** (1.0 / 3.0) + 0.5 * d + gap
    R = float(cylinder_radius)
    r_max = R - 0.5 * d - gap - math.sqrt(2.0) * jit  # max radial distance of a centre
    if r_max < 0:
        raise ValueError("cylinder too small for one grain")
    m = int(math.floor(r_max / s))
    idx = np.arange(-m, m + 1, dtype=np.float64) * s
    gx, gy = np.meshgrid(idx, idx, indexing="ij")
    gx = gx.ravel()
    gy = gy.ravel()
    rr = np.hypot(gx, gy)
    keep = rr <= r_max + 1e-12
    gx, gy, rr = gx[keep], gy[keep], rr[keep]
    order = np.lexsort((gy, gx, rr))  # by radius, then deterministic tiebreak
    gx, gy = gx[order], gy[order]
    per_layer = gx.size
    n_layers = -(-n // per_layer)
    pos = np.empty((n_layers * per_layer, 3))
    for k in range(n_layers):
        sl = slice(k * per_layer, (k + 1) * per_layer)
        pos[sl, 0] = gx + cylinder_center[0]
        pos[sl, 1] = gy + cylinder_center[1]
        pos[sl, 2] = floor_z + 0.5 * d + gap + k * s
    pos = pos[:n].copy()
    if jit > 0:
        rng = np.random.default_rng(seed)
        pos[:, :2] += rng.uniform(-jit, jit, size=(n, 2))
    return pos, R


def _check_positions(pos, diameter, cylinder_radius, center, floor_z, top_z):
    R = 0.5 * diameter
    r_xy = np.hypot(pos[:, 0] - center[0], pos[:, 1] - center[1])
    if np.any(r_xy + R > cylinder_radius * (1 + 1e-12)):
        raise ValueError("some grains cross the cylinder wall")
    if np.any(pos[:, 2] - R < floor_z - 1e-12 * max(1.0, abs(floor_z))):
        raise ValueError("some grains are below the floor")
    if np.any(pos[:, 2] >= top_z):
        raise ValueError("some grains are above top_z (box top)")
    # overlap check with a cell hash (cell = diameter, 27 neighbour cells)
    lo = pos.min(axis=0)
    cell = np.floor((pos - lo) / diameter).astype(np.int64)
    dims = cell.max(axis=0) + 3
    cell += 1
    key = (cell[:, 0] * dims[1] + cell[:, 1]) * dims[2] + cell[:, 2]
    order = np.argsort(key, kind="stable")
    skey = key[order]
    d2 = diameter * diameter * (1 - 1e-9)
    for ox in (-1, 0, 1):
        for oy in (-1, 0, 1):
            for oz in (-1, 0, 1):
                nk = key + (ox * dims[1] + oy) * dims[2] + oz
                start = np.searchsorted(skey, nk, side="left")
                stop = np.searchsorted(skey, nk, side="right")
                cnt = stop - start
                kmax = int(cnt.max()) if cnt.size else 0
                for k in range(kmax):
                    has = cnt > k
                    i = np.nonzero(has)[0]
                    j = order[start[has] + k]
                    sel = j > i
                    i, j = i[sel], j[sel]
                    if i.size:
                        dd = pos[i] - pos[j]
                        if np.any(np.einsum("ij,ij->i", dd, dd) < d2):
                            raise ValueError("initial grains overlap")


# --------------------------------------------------------------------------
# deck / data file
# --------------------------------------------------------------------------

def _write_data(path, pos, diameter, density, box, velocities=None, omegas=None):
    n = pos.shape[0]
    (xlo, xhi), (ylo, yhi), (zlo, zhi) = box
    with open(path, "w") as f:
        f.write("LIGGGHTS data file written by fbed benchmarks/liggghts/liggghts_pour.py\n\n")
        f.write(f"{n} atoms\n1 atom types\n\n")
        f.write(f"{xlo:.17g} {xhi:.17g} xlo xhi\n")
        f.write(f"{ylo:.17g} {yhi:.17g} ylo yhi\n")
        f.write(f"{zlo:.17g} {zhi:.17g} zlo zhi\n\n")
        # atom_style granular: atom-ID atom-type diameter density x y z
        f.write("Atoms\n\n")
        ids = np.arange(1, n + 1)
        table = np.column_stack([ids, np.ones(n), np.full(n, diameter),
                                 np.full(n, density), pos])
        np.savetxt(f, table, fmt=["%d", "%d", "%.17g", "%.17g",
                                  "%.17g", "%.17g", "%.17g"])
        # translational and angular velocity (zero unless given): atom-ID vx vy vz wx wy wz
        f.write("\nVelocities\n\n")
        v = np.zeros((n, 3)) if velocities is None else np.asarray(velocities, np.float64)
        w = np.zeros((n, 3)) if omegas is None else np.asarray(omegas, np.float64)
        if v.shape != (n, 3) or w.shape != (n, 3):
            raise ValueError("velocities and omegas must be (N,3) like positions")
        np.savetxt(f, np.column_stack([ids, v, w]), fmt=["%d"] + ["%.17g"] * 6)


def _deck_head(title, *, dt, skin, E, nu, e, mu, g, floor_z, R, cx, cy):
    """The part both decks share: units, the grains from data.pour, the contact law (grains and walls alike),
    gravity, the floor and the cylinder, the integrator."""
    # LIGGGHTS refuses youngsModulus < 5e6 Pa in SI units unless told otherwise
    soft = "soft_particles   yes\n" if E < 5e6 else ""
    return f"""# {title} -- generated by benchmarks/liggghts/liggghts_pour.py
units           si
atom_style      granular
atom_modify     map array
boundary        f f f
newton          off
communicate     single vel yes
processors      1 1 1
{soft}
read_data       data.pour

# skin is a distance [m] (units si): 0.1 * diameter
neighbor        {skin:.17g} bin
neigh_modify    delay 0

fix m1 all property/global youngsModulus peratomtype {E:.17g}
fix m2 all property/global poissonsRatio peratomtype {nu:.17g}
fix m3 all property/global coefficientRestitution peratomtypepair 1 {e:.17g}
fix m4 all property/global coefficientFriction peratomtypepair 1 {mu:.17g}

pair_style      gran model hertz tangential history
pair_coeff      * *

timestep        {dt:.17g}

fix gravi all gravity {g:.17g} vector 0.0 0.0 -1.0
fix floor all wall/gran model hertz tangential history primitive type 1 zplane {floor_z:.17g}
fix side  all wall/gran model hertz tangential history primitive type 1 zcylinder {R:.17g} {cx:.17g} {cy:.17g}

fix integr all nve/sphere
"""


def _deck(*, dt, steps, skin, E, nu, e, mu, g, floor_z, R, cx, cy, thermo_every):
    head = _deck_head("fbed reference pour", dt=dt, skin=skin, E=E, nu=nu, e=e, mu=mu, g=g,
                      floor_z=floor_z, R=R, cx=cx, cy=cy)
    return head + f"""
compute zmax all reduce max z
compute zavg all reduce ave z
compute rke all erotate/sphere
thermo_style    custom step atoms ke c_rke c_zmax c_zavg
thermo          {thermo_every}
thermo_modify   lost ignore norm no

# the process's CPU time (utime, stime in /proc/PID/stat) around the timed loop
shell           "cat /proc/$PPID/stat > stat.before"
run             {steps}
shell           "cat /proc/$PPID/stat > stat.after"

# ---- final state, outside the timed loop ----
compute ca all contact/atom
compute ncont all reduce sum c_ca
thermo_style    custom step atoms ke c_zmax c_zavg c_ncont
thermo_modify   lost ignore norm no
dump final all custom 1 final.dump id x y z vx vy vz omegax omegay omegaz
dump_modify final sort id format "{_DUMP_FORMAT}"
run             0 post no
"""


# every column at full double precision (the default %g keeps 6 digits: 0.1 um at 0.1 m,
# as large as the overlaps of a settled bed's top layer)
_DUMP_FORMAT = "%d" + " %.17g" * 9


# --------------------------------------------------------------------------
# log parsing
# --------------------------------------------------------------------------

_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_LOOP_RE = re.compile(r"Loop time of (" + _NUM + r") on (\d+) procs.*?for (\d+) steps with (\d+) atoms")


def _thermo_blocks(text):
    """List of thermo tables: each is (header list, rows list of float lists)."""
    blocks = []
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        ln = lines[i].split()
        if ln and ln[0] == "Step" and "Atoms" in ln:
            header = ln
            rows = []
            i += 1
            while i < len(lines):
                parts = lines[i].split()
                if len(parts) != len(header):
                    break
                try:
                    rows.append([float(p) for p in parts])
                except ValueError:
                    break
                i += 1
            blocks.append((header, rows))
        else:
            i += 1
    return blocks


def _cpu_seconds(stat_path):
    """user + system CPU seconds from a copy of /proc/PID/stat (fields 14 and 15, clock ticks)."""
    with open(stat_path) as f:
        fields = f.read().rsplit(")", 1)[1].split()  # after "pid (comm)": field 3 is fields[0]
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _parse_dump(path):
    with open(path) as f:
        lines = f.read().splitlines()
    k = next(i for i, l in enumerate(lines) if l.startswith("ITEM: ATOMS"))
    cols = lines[k].split()[2:]
    data = np.loadtxt(lines[k + 1:], ndmin=2) if len(lines) > k + 1 else np.zeros((0, len(cols)))
    return cols, data


def _run_binary(binary, wd, timeout):
    """Run ``in.pour`` in ``wd`` on one process; return (log text, stdout text, wall seconds, CPU seconds)."""
    import resource

    ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    for stale in ("log.liggghts", "final.dump"):
        p = os.path.join(wd, stale)
        if os.path.exists(p):
            os.remove(p)
    env = dict(os.environ)
    env["OMP_NUM_THREADS"] = "1"
    cmd = [binary, "-in", "in.pour", "-log", "log.liggghts",
           "-echo", "none", "-screen", "none"]
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=wd, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise RuntimeError(f"LIGGGHTS exceeded timeout of {timeout} s (killed)")
    wall_total = time.perf_counter() - t0
    ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_total = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
    out = out.decode(errors="replace")
    log_path = os.path.join(wd, "log.liggghts")
    log = open(log_path).read() if os.path.exists(log_path) else ""
    if proc.returncode != 0 or "ERROR" in log:
        err = [l for l in (log + "\n" + out).splitlines() if "ERROR" in l or "rror" in l]
        raise RuntimeError(f"LIGGGHTS failed (rc={proc.returncode}) in {wd}: "
                           + ("; ".join(err[-5:]) or out[-2000:]))
    return log, out, wall_total, cpu_total


# --------------------------------------------------------------------------
# main entry
# --------------------------------------------------------------------------

def run_pour(positions: np.ndarray,
             diameter: float, density: float,
             youngs_modulus: float, poisson_ratio: float,
             restitution: float, friction: float,
             cylinder_radius: float, cylinder_center=(0.0, 0.0),
             floor_z: float = 0.0, top_z: float | None = None,
             *, dt: float, steps: int, gravity: float = 9.81,
             workdir: str | None = None,
             skin: float | None = None, thermo_every: int | None = None,
             timeout: float = 900.0, check_overlap: bool = True,
             velocities: np.ndarray | None = None, omegas: np.ndarray | None = None) -> dict:
    """Run a LIGGGHTS pour on one core and return timing + final-state info.

    top_z is the (open) top of the non-periodic simulation box; default
    max(z)+2*diameter.  Grains that leave the box are deleted by LIGGGHTS
    and show up as ``atoms_final < atoms``.  ``skin`` defaults to
    0.1*diameter [m].  If ``workdir`` is None a temporary directory is used
    and removed afterwards; otherwise deck, data, log and final.dump stay
    there.  ``velocities`` and ``omegas`` (N,3) set the initial translational
    and angular velocities (default zero); a settled bed (grains overlap their
    neighbours and the walls) needs ``check_overlap=False``.

    Returned dict keys: version, binary, atoms, steps, dt, loop_time_s, loop_cpu_s (its CPU time),
    particle_steps_per_s, atoms_final, zmax_initial, zmax_final,
    zmean_initial, zmean_final, ke_final, contacts_final (pair contacts),
    neighbor_builds, dangerous_builds, final_positions (atoms_final,3, by id),
    final_velocities, final_omegas, thermo (list of dict rows of the timed run),
    wall_time_total_s (process incl. start-up), cpu_time_total_s (its user + system CPU time), workdir (None if temporary).
    """
    binary = find_binary()
    if binary is None:
        raise RuntimeError("LIGGGHTS binary not found (apt-get install -y liggghts)")
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0:
        raise ValueError("positions must be a non-empty (N,3) array")
    steps = int(steps)
    if steps <= 0:
        raise ValueError("steps must be positive")
    d = float(diameter)
    cx, cy = float(cylinder_center[0]), float(cylinder_center[1])
    R = float(cylinder_radius)
    if top_z is None:
        top_z = float(pos[:, 2].max()) + 2.0 * d
    if check_overlap:
        _check_positions(pos, d, R, (cx, cy), floor_z, top_z)
    if skin is None:
        skin = 0.1 * d
    if thermo_every is None:
        thermo_every = max(1, steps // 10)

    margin = 2.0 * d
    box = ((cx - R - margin, cx + R + margin),
           (cy - R - margin, cy + R + margin),
           (floor_z - margin, float(top_z)))

    tmp = None
    if workdir is None:
        tmp = tempfile.mkdtemp(prefix="liggghts_pour_")
        wd = tmp
    else:
        wd = os.path.abspath(workdir)
        os.makedirs(wd, exist_ok=True)
    try:
        _write_data(os.path.join(wd, "data.pour"), pos, d, float(density), box, velocities, omegas)
        with open(os.path.join(wd, "in.pour"), "w") as f:
            f.write(_deck(dt=float(dt), steps=steps, skin=float(skin),
                          E=float(youngs_modulus), nu=float(poisson_ratio),
                          e=float(restitution), mu=float(friction),
                          g=float(gravity), floor_z=float(floor_z), R=R,
                          cx=cx, cy=cy, thermo_every=int(thermo_every)))
        log, out, wall_total, cpu_total = _run_binary(binary, wd, timeout)
        m_ver = re.search(r"LIGGGHTS \(Version ([^)]*)\)", log + out)
        version = m_ver.group(1) if m_ver else "unknown"
        loops = [(float(a), int(b), int(c), int(dd)) for a, b, c, dd in _LOOP_RE.findall(log)]
        main = next((l for l in loops if l[2] == steps), None)
        if main is None:
            raise RuntimeError("could not find 'Loop time of ...' line for the timed run")
        loop_time, nprocs, nsteps, natoms = main
        nb = re.findall(r"Neighbor list builds\s*=\s*(\d+)", log)
        db = re.findall(r"Dangerous builds\s*=\s*(\d+)", log)

        blocks = _thermo_blocks(log)
        thermo = [dict(zip(h, r)) for h, r in [(blocks[0][0], row) for row in blocks[0][1]]] if blocks else []
        final = dict(zip(blocks[-1][0], blocks[-1][1][-1])) if blocks and blocks[-1][1] else {}

        cols, data = _parse_dump(os.path.join(wd, "final.dump"))
        ci = {c: i for i, c in enumerate(cols)}
        fpos = data[:, [ci["x"], ci["y"], ci["z"]]]
        fvel = data[:, [ci["vx"], ci["vy"], ci["vz"]]]
        fomg = data[:, [ci["omegax"], ci["omegay"], ci["omegaz"]]]

        loop_cpu = _cpu_seconds(os.path.join(wd, "stat.after")) - _cpu_seconds(os.path.join(wd, "stat.before"))
        return {
            "version": version,
            "binary": binary,
            "nprocs": nprocs,
            "atoms": natoms,
            "steps": nsteps,
            "dt": float(dt),
            "loop_time_s": loop_time,
            "loop_cpu_s": loop_cpu,
            "particle_steps_per_s": natoms * nsteps / loop_time if loop_time > 0 else float("inf"),
            "atoms_final": int(final.get("Atoms", fpos.shape[0])),
            "zmax_initial": float(pos[:, 2].max()),
            "zmax_final": float(fpos[:, 2].max()) if fpos.size else float("nan"),
            "zmean_initial": float(pos[:, 2].mean()),
            "zmean_final": float(fpos[:, 2].mean()) if fpos.size else float("nan"),
            "ke_final": float(final.get("KinEng", float("nan"))),
            "contacts_final": int(round(final["ncont"] / 2)) if "ncont" in final else None,
            "neighbor_builds": int(nb[0]) if nb else None,
            "dangerous_builds": int(db[0]) if db else None,
            "final_positions": fpos,
            "final_velocities": fvel,
            "final_omegas": fomg,
            "thermo": thermo,
            "wall_time_total_s": wall_total,
            "cpu_time_total_s": cpu_total,
            "workdir": None if tmp else wd,
        }
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)


# --------------------------------------------------------------------------
# settled random beds (the start of the fair fbed / LIGGGHTS benchmark)
# --------------------------------------------------------------------------

POUR_VERSION = 1  # bump when the pour changes, so cached beds are made again


def settled_radius(n: int, diameter: float, solid_fraction: float = 0.6, aspect: float = 2.0) -> float:
    """Cylinder radius [m] in which ``n`` grains settle (at ``solid_fraction``) to a bed ``aspect`` x R tall."""
    volume = n * math.pi / 6.0 * diameter ** 3 / solid_fraction
    return (volume / (math.pi * aspect)) ** (1.0 / 3.0)


def make_loose(n: int, diameter: float, cylinder_radius: float, spacing: float = 1.3,
               jitter: float = 0.14, seed: int = 0) -> np.ndarray:
    """Loose random start for a pour: a lattice of pitch ``spacing`` d, every site shifted by
    U(-jitter, jitter) d in x, y and z (so no two grains touch: jitter < (spacing-1)/2)."""
    pos, _ = make_lattice(n, diameter, spacing, cylinder_radius, jitter=jitter, seed=seed)
    rng = np.random.default_rng(seed + 1)
    pos[:, 2] += rng.uniform(-jitter, jitter, size=n) * diameter
    return pos


def _pour_deck(*, dt, skin, E, nu, e, mu, g, floor_z, R, cx, cy, fall_steps, chunk, max_chunks, ke_max, gamma):
    head = _deck_head("fbed settled bed", dt=dt, skin=skin, E=E, nu=nu, e=e, mu=mu, g=g,
                      floor_z=floor_z, R=R, cx=cx, cy=cy)
    return head + f"""
compute rke all erotate/sphere
thermo_style    custom step atoms ke c_rke
thermo          {chunk}
thermo_modify   lost ignore norm no

# the fall, then chunks until the kinetic energy (translational + rotational) is below ke_max [J]
run             {fall_steps}
# settling: a drag F = -gamma v (time m/gamma = 0.05 s) stops grains rolling on the surface
fix visc all viscous {gamma:.6g}
variable kk equal ke
variable rk equal c_rke
variable a loop {max_chunks}
label settle
run             {chunk}
if "$(v_kk + v_rk) < {ke_max:.6g}" then "jump SELF settled"
next a
jump SELF settle
label settled

compute ca all contact/atom
compute ncont all reduce sum c_ca
thermo_style    custom step atoms ke c_rke c_ncont
thermo_modify   lost ignore norm no
dump final all custom 1 final.dump id x y z vx vy vz omegax omegay omegaz
dump_modify final sort id format "{_DUMP_FORMAT}"
run             0 post no
"""


def pour_bed(n: int, diameter: float, density: float, youngs_modulus: float, poisson_ratio: float,
             restitution: float, friction: float, *, cylinder_radius: float | None = None,
             dt: float = 2e-5, seed: int = 0, spacing: float = 1.3, jitter: float = 0.14,
             settle_speed: float = 1e-3, max_time: float = 3.0, gravity: float = 9.81,
             cache_dir: str | None = None, timeout: float = 3600.0) -> dict:
    """Pour ``n`` random grains into a z-cylinder (floor at z = 0) in LIGGGHTS and let them settle.

    The grains start loose (:func:`make_loose`, solid fraction ~0.24) and fall under gravity
    with the given contact law at step ``dt`` (a pour: a longer step and a lower restitution than
    the benchmark's are fine, the result is only a start); then the run goes on in chunks of 0.01 s
    with a viscous drag on every grain (time m/gamma = 0.05 s, so grains rolling on the surface
    stop too) until the kinetic energy (translational + rotational) is below that of every grain moving at
    ``settle_speed`` [m/s]; RuntimeError if that takes more than ``max_time`` [s] simulated.

    With ``cache_dir`` the settled state is kept there as ``bed_n<N>_<key>.npz`` (key: a hash of
    every parameter and POUR_VERSION) and read back on the next call instead of pouring again.
    Returns a dict: position, velocity, omega (N,3 by id), cylinder_radius, floor_z, key, cached,
    simulated_time, pour_wall_s, contacts (LIGGGHTS's pair count), path.
    """
    import hashlib
    import json

    d = float(diameter)
    R = float(cylinder_radius) if cylinder_radius else settled_radius(n, d)
    params = dict(version=POUR_VERSION, n=int(n), d=d, rho=float(density), E=float(youngs_modulus),
                  nu=float(poisson_ratio), e=float(restitution), mu=float(friction), R=R, dt=float(dt),
                  seed=int(seed), spacing=float(spacing), jitter=float(jitter),
                  settle_speed=float(settle_speed), g=float(gravity))
    key = hashlib.sha1(json.dumps(params, sort_keys=True).encode()).hexdigest()[:12]
    path = os.path.join(cache_dir, f"bed_n{n}_{key}.npz") if cache_dir else None
    if path and os.path.exists(path):
        z = np.load(path)
        return {"position": z["position"], "velocity": z["velocity"], "omega": z["omega"],
                "cylinder_radius": float(z["cylinder_radius"]), "floor_z": 0.0, "key": key, "cached": True,
                "simulated_time": float(z["simulated_time"]), "pour_wall_s": float(z["pour_wall_s"]),
                "contacts": int(z["contacts"]), "path": path, "params": params}

    binary = find_binary()
    if binary is None:
        raise RuntimeError("LIGGGHTS binary not found (apt-get install -y liggghts)")
    pos = make_loose(n, d, R, spacing, jitter, seed)
    h0 = float(pos[:, 2].max())
    h1 = 2.0 * R  # about the settled height
    fall_steps = max(1, int(math.sqrt(2.0 * max(h0 - h1, d) / gravity) / dt))
    chunk = max(1, int(round(0.01 / dt)))
    max_chunks = max(1, int((max_time - fall_steps * dt) / (chunk * dt)))
    mass = density * math.pi / 6.0 * d ** 3
    ke_max = 0.5 * n * mass * settle_speed ** 2
    margin = 2.0 * d
    box = ((-R - margin, R + margin), (-R - margin, R + margin), (-margin, h0 + 2.0 * d))
    wd = tempfile.mkdtemp(prefix="liggghts_bed_")
    try:
        _write_data(os.path.join(wd, "data.pour"), pos, d, float(density), box)
        with open(os.path.join(wd, "in.pour"), "w") as f:
            f.write(_pour_deck(dt=float(dt), skin=0.1 * d, E=float(youngs_modulus), nu=float(poisson_ratio),
                               e=float(restitution), mu=float(friction), g=float(gravity), floor_z=0.0, R=R,
                               cx=0.0, cy=0.0, fall_steps=fall_steps, chunk=chunk, max_chunks=max_chunks,
                               ke_max=ke_max, gamma=mass / 0.05))
        log, out, wall, _ = _run_binary(binary, wd, timeout)
        blocks = _thermo_blocks(log)
        final = dict(zip(blocks[-1][0], blocks[-1][1][-1]))
        steps = int(final["Step"])
        ke = final["KinEng"] + final["rke"]
        if ke >= ke_max:
            raise RuntimeError(f"the {n}-grain pour did not settle in {max_time} s simulated "
                               f"(kinetic energy {ke:.3g} J > {ke_max:.3g} J): raise max_time")
        if int(final["Atoms"]) != n:
            raise RuntimeError(f"the pour lost {n - int(final['Atoms'])} grains")
        cols, data = _parse_dump(os.path.join(wd, "final.dump"))
        ci = {c: i for i, c in enumerate(cols)}
        res = {"position": data[:, [ci["x"], ci["y"], ci["z"]]],
               "velocity": data[:, [ci["vx"], ci["vy"], ci["vz"]]],
               "omega": data[:, [ci["omegax"], ci["omegay"], ci["omegaz"]]],
               "cylinder_radius": R, "floor_z": 0.0, "key": key, "cached": False,
               "simulated_time": steps * dt, "pour_wall_s": wall,
               "contacts": int(round(final["ncont"] / 2)), "path": path, "params": params}
    finally:
        shutil.rmtree(wd, ignore_errors=True)
    if path:
        os.makedirs(cache_dir, exist_ok=True)
        tmp = path + ".tmp.npz"
        np.savez(tmp, **{k: res[k] for k in ("position", "velocity", "omega", "cylinder_radius",
                                             "simulated_time", "pour_wall_s", "contacts")},
                 params=json.dumps(params))
        os.replace(tmp, path)
    return res


# --------------------------------------------------------------------------
# CLI benchmark
# --------------------------------------------------------------------------

def _main(argv=None):
    import argparse
    p = argparse.ArgumentParser(description="Single-core LIGGGHTS pour benchmark (fbed reference)")
    p.add_argument("--n", type=int, nargs="+", default=[10000], help="grain count(s)")
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--dt", type=float, default=2e-6)
    p.add_argument("--diameter", type=float, default=2e-3)
    p.add_argument("--spacing", type=float, default=1.05, help="lattice pitch / diameter")
    p.add_argument("--radius", type=float, default=None,
                   help="cylinder radius [m]; default: column about as tall as wide")
    p.add_argument("--jitter", type=float, default=0.0,
                   help="random x/y shift of lattice sites, fraction of d (< (spacing-1)/2)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--density", type=float, default=2500.0)
    p.add_argument("--E", type=float, default=5e6)
    p.add_argument("--nu", type=float, default=0.3)
    p.add_argument("--e", type=float, default=0.9)
    p.add_argument("--mu", type=float, default=0.5)
    p.add_argument("--workdir", default=None, help="keep deck/log/dump here (per-N subfolder)")
    a = p.parse_args(argv)

    if not available():
        print("LIGGGHTS not found: apt-get install -y liggghts")
        return 2
    rows = []
    ok = True
    for n in a.n:
        pos, R = make_lattice(n, a.diameter, a.spacing, a.radius,
                              jitter=a.jitter, seed=a.seed)
        wd = os.path.join(a.workdir, f"n{n}") if a.workdir else None
        r = run_pour(pos, a.diameter, a.density, a.E, a.nu, a.e, a.mu, R,
                     dt=a.dt, steps=a.steps, workdir=wd)
        sane = r["atoms_final"] == n and r["zmax_final"] < r["zmax_initial"]
        ok &= sane
        rows.append((n, R, r, sane))
    print(f"LIGGGHTS {rows[0][2]['version']}  (1 MPI rank, OMP_NUM_THREADS=1)  dt={a.dt:g} s")
    print(f"{'N':>8} {'R_cyl[m]':>9} {'steps':>6} {'wall[s]':>9} {'p-steps/s':>11} "
          f"{'contacts':>8} {'zmax0[m]':>9} {'zmax[m]':>9} {'left':>7} sanity")
    for n, R, r, sane in rows:
        print(f"{n:>8} {R:>9.4f} {r['steps']:>6} {r['loop_time_s']:>9.3f} "
              f"{r['particle_steps_per_s']:>11.4g} {str(r['contacts_final']):>8} "
              f"{r['zmax_initial']:>9.5f} {r['zmax_final']:>9.5f} {r['atoms_final']:>7} "
              f"{'ok' if sane else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(_main())
