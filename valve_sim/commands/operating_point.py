# Copyright 2026 valve_sim developers
#
# Licensed under the Apache License, Version 2.0 (the "License");
# you may not use this file except in compliance with the License.
# You may obtain a copy of the License at
#
#     http://www.apache.org/licenses/LICENSE-2.0
#
# Unless required by applicable law or agreed to in writing, software
# distributed under the License is distributed on an "AS IS" BASIS,
# WITHOUT WARRANTIES OR CONDITIONS OF ANY KIND, either express or implied.
# See the License for the specific language governing permissions and
# limitations under the License.

"""
Report the exact steady state at an inlet flow: pressures, openings, flows, forces and modes.

The numbers behind docs/model.md's force and flow balances and stability margins.
"""

from valve_sim.commands.simulate import add_parameter_arguments, flow_value, load_from_arguments
from valve_sim.core.scenario import LITRE_PER_MINUTE


def add_arguments(parser):
    add_parameter_arguments(parser)
    parser.add_argument(
        '--flow',
        type=flow_value,
        action='append',
        metavar='Q',
        help='inlet flow (e.g. 5L/min); repeatable (default 5L/min and 20L/min)',
    )


def report(params, inlet_flow):
    from valve_sim.core.linear import oscillatory_modes
    from valve_sim.core.model import coefficients, flows
    from valve_sim.core.steady_state import steady_state

    c = coefficients(params)
    state = steady_state(params, inlet_flow)
    p_s, p_m, p_p, p_c, x, _, y, _ = state
    _, q_m2, _, q_c, q_s, q_p = (q / LITRE_PER_MINUTE for q in flows(state, c))
    print(f'inlet flow {inlet_flow / LITRE_PER_MINUTE:.3f} L/min ({inlet_flow:.4e} m^3/s)')
    print(
        f'  pressures [MPa]  p_s {p_s / 1e6:.4f}  p_m {p_m / 1e6:.4f}  '
        f'p_p {p_p / 1e6:.4f}  p_c {p_c / 1e6:.4f}'
    )
    print(
        f'  openings [um]    x {x * 1e6:.2f}  '
        f'(first throttle x + h = {(x + c.first_throttle_clearance) * 1e6:.2f})'
        f'  y {y * 1e6:.2f}'
    )
    print(
        f'  flows [L/min]    main q_m1 = q_m2 = {q_m2:.4f}  '
        f'bearings q_n = orifice q_c = {q_c:.4f}  '
        f'rod leak q_s {q_s:.4f}  poppet q_p {q_p:.4f}'
    )
    print(
        f'  main valve [N]   alpha_s p_s {c.supply_force_area * p_s:.2f}  '
        f'alpha_m p_m {c.intermediate_force_area * p_m:.2f}'
        f'  -A_p p_p {-c.back_area * p_p:.2f}  '
        f'-k_m (x + x_0) {-c.main_spring_stiffness * (x + c.main_spring_preload):.2f}'
    )
    print(
        f'  poppet [N]       A_s p_s {c.rod_area * p_s:.2f}  -k_p (y + y_0) '
        f'{-c.pilot_spring_stiffness * (y + c.pilot_spring_preload):.2f}  '
        f'-K_f y p_c {-c.flow_force_gain * y * p_c:.3f}'
    )
    modes = ', '.join(
        f'{f:.1f} Hz (zeta {z:.4f})' for f, z in oscillatory_modes(params, inlet_flow)
    )
    print(f'  linear modes     {modes}')


def run(args):
    from valve_sim.core.steady_state import cracking_pressure

    params, _ = load_from_arguments(args)
    print(f'main valve cracking pressure: {cracking_pressure(params) / 1e6:.4f} MPa')
    for inlet_flow in args.flow or (5 * LITRE_PER_MINUTE, 20 * LITRE_PER_MINUTE):
        report(params, inlet_flow)
    return 0
