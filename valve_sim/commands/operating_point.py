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
--tank-pressure puts the valve's outlet on a pressurised tank (gauge): every pressure
and the cracking pressure rise by it (docs/model.md, "Back pressure").
--mode-sensitivity adds how each linear mode's frequency and decay rate move per +1 %
of each parameter (preset held). --json prints the same as one JSON document under
the stable key names of docs/model.md ("operating-point --json"), all SI.
"""


from valve_sim.commands.options import add_options, flow_value, load_from_arguments
from valve_sim.core.flow_step import LITRE_PER_MINUTE
from valve_sim.core.output_files import json_text


def add_arguments(parser):
    add_options(parser, '--params', '--set', '--preset-pressure', '--tank-pressure')
    parser.add_argument('--flow', type=flow_value, action='append', metavar='Q',
                        help='inlet flow (e.g. 5L/min); repeatable (default 5L/min and 20L/min)')
    parser.add_argument('--mode-sensitivity', action='store_true',
                        help="each linear mode's change of frequency and decay rate per +1 %% of "
                        'each parameter, the preset held (about a second per flow)')
    add_options(parser, '--json', help='print the operating points as JSON (SI units)')


def operating_point(params, inlet_flow, tank_pressure=0.0):
    """
    Return the steady state at inlet_flow [m^3/s] as a JSON-ready dict (SI units).

    Keys (stable, documented in docs/model.md): inlet_flow, tank_pressure [Pa gauge],
    pressures {supply, intermediate, pilot, poppet_chamber} [Pa gauge], openings
    {main_valve, first_throttle, poppet} [m], flows {main, pilot, bearings,
    damping_orifice, rod_leakage, relief} [m^3/s], main_valve_forces and
    poppet_forces [N], modes [{frequency_hz, damping_ratio, decay_rate, name}] of the
    oscillatory modes, slowest first.
    """
    from valve_sim.core.linear import modes
    from valve_sim.core.coefficients import coefficients
    from valve_sim.core.model import flows, relief_flows
    from valve_sim.core.steady_state import steady_state

    c = coefficients(params)
    state = steady_state(params, inlet_flow, tank_pressure=tank_pressure, stable=False)
    p_s, p_m, p_p, p_c, x, _, y, _ = (float(v) for v in state)
    _, q_m2, q_n, q_c, q_s, q_p = (float(q) for q in flows(state, c, tank_pressure))
    return {
        'inlet_flow': inlet_flow,
        'tank_pressure': tank_pressure,
        'pressures': {
            'supply': p_s,
            'intermediate': p_m,
            'pilot': p_p,
            'poppet_chamber': p_c,
        },
        'openings': {
            'main_valve': x,
            'first_throttle': x + c.first_throttle_clearance,
            'poppet': y,
        },
        'flows': {
            'main': q_m2,
            'pilot': q_p,
            'bearings': q_n,
            'damping_orifice': q_c,
            'rod_leakage': q_s,
            'relief': float(sum(relief_flows(state, c, tank_pressure))),
        },
        'main_valve_forces': {
            'supply': c.supply_force_area * p_s,
            'intermediate': c.intermediate_force_area * p_m,
            'pilot': -c.back_area * p_p,
            'spring': -c.main_spring_stiffness * (x + c.main_spring_preload),
            'tank': c.tank_force_area * tank_pressure,
        },
        'poppet_forces': {
            'rod': c.rod_area * p_s,
            'poppet_chamber': c.poppet_chamber_area * p_c,
            'spring': -c.pilot_spring_stiffness * (y + c.pilot_spring_preload),
            'flow': -c.flow_force_gain * y * (p_c - tank_pressure),
            'tank': -c.seat_area * tank_pressure,
        },
        'modes': [
            mode_entry(mode)
            for mode in modes(params, inlet_flow, tank_pressure)
            if mode.frequency_hz > 0
        ],
    }


def mode_entry(mode):
    """Return a core.linear.Mode as a JSON-ready dict."""
    return {
        'frequency_hz': mode.frequency_hz,
        'damping_ratio': mode.damping_ratio,
        'decay_rate': mode.decay_rate,
        'name': mode.name,
    }


def sensitivity(params, inlet_flow, preset_pressure, tank_pressure=0.0):
    """
    Return the mode sensitivity at inlet_flow [m^3/s] as a JSON-ready dict (SI units).

    Keys: modes [mode_entry, with states] (every mode, oscillatory or not, slowest
    first), parameters [{name, symbol, value, frequency_hz, decay_rate}]: per
    parameter the change of each mode's frequency [Hz] and decay rate [1/s] per +1 %
    of it, in the order of modes; preset_pressure [Pa] held; at tank_pressure [Pa gauge].
    """
    from valve_sim.core.linear import mode_sensitivity
    from valve_sim.core.parameters import SPECS

    base, table = mode_sensitivity(
        params, inlet_flow, preset_pressure, tank_pressure=tank_pressure
    )
    return {
        'per_percent': 1.0,
        'preset_pressure': preset_pressure,
        'modes': [{**mode_entry(mode), 'states': list(mode.states)} for mode in base],
        'parameters': [
            {
                'name': name,
                'symbol': SPECS[name].symbol,
                'value': params[name],
                'frequency_hz': [change[0] for change in changes],
                'decay_rate': [change[1] for change in changes],
            }
            for name, changes in table.items()
        ],
    }


def report(point):
    """Print one operating_point() for people: pressures in MPa, openings in µm, flows in L/min."""
    pressure, opening, flow = point['pressures'], point['openings'], point['flows']
    main, poppet = point['main_valve_forces'], point['poppet_forces']
    litres = {name: value / LITRE_PER_MINUTE for name, value in flow.items()}
    print(
        f'inlet flow {point["inlet_flow"] / LITRE_PER_MINUTE:.3f} L/min '
        f'({point["inlet_flow"]:.4e} m^3/s)'
        + (f', tank at {point["tank_pressure"] / 1e6:.4f} MPa' if point['tank_pressure'] else '')
    )
    print(
        f'  pressures [MPa]  p_s {pressure["supply"] / 1e6:.4f}  '
        f'p_m {pressure["intermediate"] / 1e6:.4f}  p_p {pressure["pilot"] / 1e6:.4f}  '
        f'p_c {pressure["poppet_chamber"] / 1e6:.4f}'
    )
    print(
        f'  openings [µm]    x {opening["main_valve"] * 1e6:.2f}  '
        f'(first throttle x + h = {opening["first_throttle"] * 1e6:.2f})'
        f'  y {opening["poppet"] * 1e6:.2f}'
    )
    print(
        f'  flows [L/min]    main q_m1 = q_m2 = {litres["main"]:.4f}  '
        f'bearings q_n = orifice q_c = {litres["damping_orifice"]:.4f}  '
        f'rod leak q_s {litres["rod_leakage"]:.4f}  pilot (poppet) q_p {litres["pilot"]:.4f}'
    )
    print(
        f'  main valve [N]   alpha_s p_s {main["supply"]:.2f}  '
        f'alpha_m p_m {main["intermediate"]:.2f}  -A_p p_p {main["pilot"]:.2f}  '
        f'-k_m (x + x_0) {main["spring"]:.2f}'
        + (f'  A_t p_t {main["tank"]:.2f}' if point['tank_pressure'] else '')
    )
    print(
        f'  poppet [N]       A_s p_s {poppet["rod"]:.2f}  -k_p (y + y_0) {poppet["spring"]:.2f}  '
        f'-K_f y {"(p_c - p_t)" if point["tank_pressure"] else "p_c"} {poppet["flow"]:.3f}  '
        f'A_c p_c {poppet["poppet_chamber"]:.3f}'
        + (f'  -A_v p_t {poppet["tank"]:.2f}' if point['tank_pressure'] else '')
    )
    modes = ', '.join(
        f'{mode["frequency_hz"]:.1f} Hz (zeta {mode["damping_ratio"]:.4f}, '
        f'decay {mode["decay_rate"]:.3g} 1/s, {mode["name"]})'
        for mode in point['modes']
    )
    print(f'  linear modes     {modes}')
    if 'mode_sensitivity' in point:
        report_sensitivity(point['mode_sensitivity'])


def report_sensitivity(table):
    """Print a mode_sensitivity table: per parameter, each oscillatory mode's df and d(decay)."""
    shown = [k for k, mode in enumerate(table['modes']) if mode['frequency_hz'] > 0]
    print(
        '  mode sensitivity per +1 % of each parameter, preset held at '
        f'{table["preset_pressure"] / 1e6:.4f} MPa (df [Hz], d decay [1/s]):'
    )
    heads = [
        f'{table["modes"][k]["name"]} {table["modes"][k]["frequency_hz"]:.0f} Hz' for k in shown
    ]
    print(f'    {"parameter":<36}' + ''.join(f'{head:>26}' for head in heads))
    for row in table['parameters']:
        label = f'{row["name"]} ({row["symbol"]})'
        print(f'    {label:<36}' + ''.join(
            f'{row["frequency_hz"][k]:>+13.3f}{row["decay_rate"][k]:>+13.3f}' for k in shown
        ))
    others = [mode for mode in table['modes'] if mode['frequency_hz'] == 0]
    if others:
        print('    (the non-oscillatory modes, ' + ', '.join(
            f'{mode["name"]} {mode["decay_rate"]:.3g} 1/s' for mode in others
        ) + ', are in --json)')


def run(args):
    from valve_sim.core.steady_state import cracking_pressure

    loaded = load_from_arguments(args)
    params, settings = loaded.params, loaded.settings
    tank = settings['tank_pressure']
    inlet_flows = args.flow or (5 * LITRE_PER_MINUTE, 20 * LITRE_PER_MINUTE)
    preset = cracking_pressure(params)  # the valve's setting: the tank at ambient
    cracking = cracking_pressure(params, tank_pressure=tank)

    def point(inlet_flow):
        entry = operating_point(params, inlet_flow, tank)
        if args.mode_sensitivity:
            entry['mode_sensitivity'] = sensitivity(params, inlet_flow, preset, tank)
        return entry

    if args.json:
        document = {
            'cracking_pressure': cracking,
            'tank_pressure': tank,
            'operating_points': [point(q) for q in inlet_flows],
        }
        print(json_text(document))
        return 0
    print(
        f'main valve cracking pressure: {cracking / 1e6:.4f} MPa'
        + (f' (gauge; the tank at {tank / 1e6:.4f} MPa, the setting {preset / 1e6:.4f} MPa '
           'above it)' if tank else '')
    )
    for inlet_flow in inlet_flows:
        report(point(inlet_flow))
    return 0
