"""The MPC's whole solver as machine code, callable from numba (the compiled run loop).

``controller.mpc`` solves its NLP with CasADi's ``sqpmethod`` (HPIPM for the QPs), driven
from Python, with only the derivatives compiled (``controller.codegen``). Here the whole
solver is written out as C by CasADi (``CodeGenerator`` of the ``nlpsol``: the SQP loop, the
line search, the Gauss-Newton Hessian, HPIPM's interface) together with the prediction's RK4
chunk (``MPCProblem.rk4_chunk``), compiled once into a shared library (cached on disk by
``controller.codegen.compiled_library``, linked to the HPIPM and BLASFEO libraries that ship
with CasADi) and called without Python: ``call_casadi`` is a numba intrinsic that calls a
generated function through its address, with CasADi's calling convention
``f(const double** arg, double** res, casadi_int* iw, double* w, int mem)``.

The NLP is the one of ``controller.mpc_problem.MPCProblem``, its shooting steps as calls of one
function (the form of its compiled Jacobian, ``MPCProblem._compile``), with the same solver
options, so a solve is
the event loop's solve to rounding (tests/test_compiled_mpc.py: the same iterate to 1e-9 on
cold and warm starts). Its cost's weights (``MPCProblem.weights``: the bandwidth rule's q_θ, q_ω,
r, the terminal P_i, the tilt slack's ρ1, ρ2) are parameters appended to the NLP's, and the
torque limit and the tilt limit enter through the bounds, which are inputs already: one machine
code serves every MPC that differs only in ``WEIGHT_FIELDS`` (a co-design varies the bandwidth
continuously), built once per process and compiled once per machine.

One correction to CasADi's C code: its HPIPM interface writes only
some fields of HPIPM's ``d_ocp_qp_ipm_arg`` (CasADi 3.8 with the HPIPM it ships): the others
(``dual_gap_max``, ``lam0_min``, ``t0_min``, ``t0_init``, ``update_fact_exit``) were left as
stack garbage and the QPs failed in speed mode; the patch sets them to HPIPM's defaults for
the mode, as CasADi's own plugin (``d_ocp_qp_ipm_arg_set_default``) does.

Mirrors: ``latency.compiled.mpc._mpc`` runs ``MPCController._command`` with these functions.
"""

from __future__ import annotations

import ctypes
import json
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numpy.typing import NDArray

from controller.codegen import compiled_library
from controller.mpc import RUNTIME_FIELDS

#: ``MPCConfig`` fields that set only the cost's weights or the bounds: parameters and inputs
#: of the machine code, not part of its key.
WEIGHT_FIELDS = frozenset({"bandwidth_rad_s", "damping", "torque_limit_Nm",
                           "torque_limit_margin", "tilt_slack_l1", "tilt_slack_l2",
                           "tilt_max_deg"})

#: The line of CasADi's generated HPIPM set-up after which the missing options are set.
_HPIPM_LAST_OPTION = "  p.hpipm_options.memsize = 0;"
_HPIPM_DEFAULTS = """
  {
    /* the fields CasADi's code generator leaves unset: HPIPM's defaults for the mode */
    struct d_ocp_qp_ipm_arg defaults;
    d_ocp_qp_ipm_arg_set_default((enum hpipm_mode) p.hpipm_options.mode, &defaults);
    p.hpipm_options.dual_gap_max = defaults.dual_gap_max;
    p.hpipm_options.lam0_min = defaults.lam0_min;
    p.hpipm_options.t0_min = defaults.t0_min;
    p.hpipm_options.t0_init = defaults.t0_init;
    p.hpipm_options.update_fact_exit = defaults.update_fact_exit;
  }"""


@intrinsic
def call_casadi(typingctx, fn, arg, res, iw, w):
    """Call the generated CasADi function at address ``fn`` with the addresses of its
    argument and result pointer arrays, integer and real work arrays (memory 0); returns its
    status (0: success). All arguments are integers (``array.ctypes.data``)."""
    if not all(isinstance(a, types.Integer) for a in (fn, arg, res, iw, w)):
        return None
    sig = types.int32(fn, arg, res, iw, w)

    def codegen(context, builder, signature, args):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.IntType(32), [ptr, ptr, ptr, ptr, ir.IntType(32)])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        return builder.call(f, [builder.inttoptr(a, ptr) for a in args[1:]]
                            + [ir.Constant(ir.IntType(32), 0)])

    return sig, codegen


@dataclass(frozen=True)
class MachineFunction:
    """A generated function ready for ``call_casadi``: its address, the pointer arrays and
    work arrays, and its inputs and outputs packed into two flat arrays (``inputs[offsets_in[k]
    : offsets_in[k + 1]]`` is input k). Write the inputs, call, read the outputs, all in one
    compiled function: the arrays (and the generated code's static memory) are shared by the
    process, and a numba function without ``nogil`` holds the GIL, so threads take turns."""

    address: int
    arg: NDArray[np.int64]
    res: NDArray[np.int64]
    iw: NDArray[np.int64]
    w: NDArray[np.float64]
    inputs: NDArray[np.float64]
    outputs: NDArray[np.float64]
    offsets_in: NDArray[np.int64]
    offsets_out: NDArray[np.int64]

    def call_args(self) -> tuple[int, int, int, int, int]:
        """The arguments of ``call_casadi``."""
        return (self.address, self.arg.ctypes.data, self.res.ctypes.data, self.iw.ctypes.data,
                self.w.ctypes.data)


@dataclass(frozen=True)
class MachineMPC:
    """The MPC's solver (inputs x0, p, lbx, ubx, lbg, ubg, lam_x0, lam_g0; outputs x, f, g,
    lam_x, lam_g, lam_p, as ``casadi.nlpsol``) and RK4 chunk (x (7), T (3 x chunk), h (chunk)
    -> x after each step (7 x chunk)) as machine code; ``library`` is the shared library."""

    solver: MachineFunction
    rk4_chunk: MachineFunction
    library: Path


def weight_values(problem) -> NDArray[np.float64]:
    """The weights of ``problem`` (``MPCProblem.weights``) as the machine code's extra parameters:
    q_θ (3), q_ω (3), r, P_1..P_3 (each 2 x 2 column by column), ρ1, ρ2."""
    Qth, Qw, r, P, rho1, rho2 = problem.weights()
    return np.concatenate([Qth, Qw, [r], *(np.ravel(Pi, order="F") for Pi in P), [rho1, rho2]])


def machine_mpc(problem) -> MachineMPC | None:
    """The machine code of ``problem`` (a ``MPCProblem`` with the SQP + HPIPM
    solver and the Gauss-Newton Hessian), built once per process for all problems that differ
    only in ``WEIGHT_FIELDS`` (their weights are parameters: ``weight_values``); None without
    a C compiler or when compiling fails (a warning says why)."""
    key = json.dumps([problem.config.model_dump(mode="json",
                                                exclude=set(RUNTIME_FIELDS | WEIGHT_FIELDS)),
                      problem.params.model_dump(mode="json")], sort_keys=True)
    if key not in _MACHINES:
        _MACHINES[key] = _build(problem)
    return _MACHINES[key]


#: The machine codes built in this process, by ``machine_mpc``'s key.
_MACHINES: dict[str, MachineMPC | None] = {}


def _build(problem) -> MachineMPC | None:
    """Generate, compile (or load) and open the machine code of ``problem``'s structure."""
    cfg = problem.config
    if cfg.solver != "sqp_hpipm" or cfg.hessian != "gauss_newton":
        raise ValueError(f"the machine-code MPC needs solver 'sqp_hpipm' with the Gauss-Newton "
                         f"Hessian, got {cfg.solver!r} with {cfg.hessian!r}")
    x, T = ca.SX.sym("x", 7), ca.SX.sym("T", 3)
    phi = problem._shooting_step(cfg.step_s, cfg.rk4_substeps)
    step = ca.Function("mpc_phi", [x, T], [phi(x, T)], {"never_inline": True})
    Qth, Qw, r = ca.SX.sym("q_theta", 3), ca.SX.sym("q_omega", 3), ca.SX.sym("r")
    P = [ca.SX.sym(f"P{i}", 2, 2) for i in range(3)]
    rho1, rho2 = ca.SX.sym("rho1"), ca.SX.sym("rho2")
    nlp, _, tilt_rows, ball_rows = problem._nlp_graph(step, (Qth, Qw, r, P, rho1, rho2))
    nlp["p"] = ca.vertcat(nlp["p"], Qth, Qw, r, *(ca.vec(Pi) for Pi in P), rho1, rho2)
    hess = problem._gauss_newton_hessian(nlp, tilt_rows, ball_rows)
    options = {k: v for k, v in problem._solver_options().items() if k != "jac_fg"}
    options["hess_lag"] = hess
    options["calc_lam_p"] = False  # the multipliers of the parameters: not used, not computed
    solver = ca.nlpsol("mpc_machine", "sqpmethod", nlp, options)
    rk4_chunk = problem.rk4.mapaccum("mpc_machine_rk4", problem.chunk)
    main = ca.CodeGenerator("mpc_machine.c", {"with_header": False})
    main.add(solver)
    main.add(rk4_chunk)
    source = main.dump()
    if _HPIPM_LAST_OPTION not in source:
        raise RuntimeError("CasADi's generated HPIPM set-up changed: check the options patch")
    source = source.replace(_HPIPM_LAST_OPTION, _HPIPM_LAST_OPTION + _HPIPM_DEFAULTS)
    # The Hessian is an external dependency of the generated solver: its own unit.
    hess_code = ca.CodeGenerator("mpc_machine_hess.c", {"with_header": False})
    hess_code.add(hess)
    folder = Path(ca.__file__).parent
    flags = (f"-I{folder / 'include'}", f"-L{folder}", "-lhpipm", "-lblasfeo",
             f"-Wl,-rpath,{folder}", "-Wl,-Bsymbolic")
    lib_path = compiled_library([source, hess_code.dump()], "mpc_machine", flags)
    if lib_path is None:
        return None
    lib = ctypes.CDLL(str(lib_path))
    return MachineMPC(machine_function(lib, solver), machine_function(lib, rk4_chunk), lib_path)


def machine_function(lib: ctypes.CDLL, f: ca.Function) -> MachineFunction:
    """The generated ``f`` of ``lib`` with its arrays (``MachineFunction``)."""
    name = f.name()
    getattr(lib, f"{name}_incref")()
    checkout = getattr(lib, f"{name}_checkout")
    checkout.restype = ctypes.c_int
    if checkout() != 0:
        raise RuntimeError(f"{name}: memory 0 is taken")
    sizes = [ctypes.c_longlong() for _ in range(4)]
    getattr(lib, f"{name}_work")(*(ctypes.byref(s) for s in sizes))
    n_arg, n_res, n_iw, n_w = (max(int(s.value), 1) for s in sizes)
    sizes_in = [f.nnz_in(i) for i in range(f.n_in())]
    sizes_out = [f.nnz_out(i) for i in range(f.n_out())]
    offsets_in = np.r_[0, np.cumsum(sizes_in)].astype(np.int64)
    offsets_out = np.r_[0, np.cumsum(sizes_out)].astype(np.int64)
    inputs, outputs = np.zeros(offsets_in[-1]), np.zeros(offsets_out[-1])
    arg, res = np.zeros(n_arg, dtype=np.int64), np.zeros(n_res, dtype=np.int64)
    arg[: f.n_in()] = inputs.ctypes.data + 8 * offsets_in[:-1]
    res[: f.n_out()] = outputs.ctypes.data + 8 * offsets_out[:-1]
    address = ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
    assert address is not None
    return MachineFunction(address, arg, res, np.zeros(n_iw, dtype=np.int64), np.zeros(n_w),
                           inputs, outputs, offsets_in, offsets_out)
