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
The parameter catalogue, and the docs' parameter tables held against it.

A table is a parameter table when its first column is named parameter, name or setting
and it has a column of symbols, units, defaults (values) or limits (ranges). Every row
names parameters (`backticked`, or plain in docs/model.md); each must be in the
catalogue (or be one of the nodes' few non-numeric parameters declared outside it),
with the catalogue's symbol, unit, limits and default (to the digits the table prints;
the defaults of the model and the settings are config/reference.yaml's). Every
catalogue entry must be in some table.
"""

from decimal import Decimal, InvalidOperation
from pathlib import Path
import re

import pytest
from valve_sim.core.catalogue import (
    ANALYSER_DOUBLES,
    CATALOGUE,
    LIVE_NAMES,
    SENSOR_PREFIX,
    SENSOR_SETTINGS,
    SENSOR_TOPICS,
    split,
)
from valve_sim.core.model import P_C, P_S, STATE_NAMES
from valve_sim.core.parameters import load_parameters

DOCS = Path(__file__).resolve().parents[2] / 'docs'
PAGES = ('valve_node.md', 'analyser.md', 'faults.md', 'model.md')
NAME_HEADERS = ('parameter', 'name', 'setting')
COLUMNS = {  # header: what the column holds
    'symbol': 'symbol', 'sym.': 'symbol', 'unit': 'unit', 'default': 'default',
    'value': 'default', 'limits': 'limits', 'range': 'limits',
}
# The nodes' string, list and integer parameters declared outside the catalogue: analyser
# PLAIN_PARAMETERS (valve_sim.ros.analyser_node), the statuses' hardware_id
# and diagnostic_updater.period (valve_sim.ros.diagnostics), valve_node's frame_prefix and
# inlet_flow_reliability.
OUTSIDE = {
    'topics', 'output_dir', 'bag_folder', 'queue_depth', 'supply_pressure_topic',
    'main_valve_topic', 'main_valve_joint', 'inlet_flow_topic', 'inlet_flow_joint',
    'tank_pressure_topic', 'hardware_id', 'frame_prefix', 'inlet_flow_reliability',
    'lockstep_inputs', 'diagnostic_updater.period',
}
GREEK = {'ρ': 'rho', 'μ': 'mu', 'β': 'beta', 'δ': 'delta', 'θ': 'theta', 'Δ': 'd'}


def cells(line):
    return [cell.strip() for cell in line.strip().strip('|').split('|')]


def parameter_tables(page):
    """Yield (line number, {column: cell}) of each row of page's parameter tables."""
    lines = (DOCS / page).read_text(encoding='utf-8').splitlines()
    for number, line in enumerate(lines):
        if not line.startswith('|') or not lines[number + 1].startswith('|---'):
            continue
        if number and lines[number - 1].startswith('|'):
            continue
        header = [h.lower() for h in cells(line)]
        columns = {i: COLUMNS[h] for i, h in enumerate(header) if h in COLUMNS}
        if header[0] not in NAME_HEADERS or not columns:
            continue
        row = number + 2
        while row < len(lines) and lines[row].startswith('|'):
            values = cells(lines[row])
            yield f'{page}:{row + 1}', header[0], values[0], {
                kind: values[i] for i, kind in columns.items() if i < len(values)
            }
            row += 1


def names_of(cell, header):
    """
    [(name, i, n)] of a row's first cell: each name and its value, the i-th of n in the row.

    Several names for 'K_1..3' (values 1.9958, -0.4559, 0.1186) or a list of names; a
    sensor setting names it on each topic, with the row's one value.
    """
    names = re.findall(r'`([^`]+)`', cell) or [cell.replace(' (setting)', '').strip()]
    ranged = re.fullmatch(r'(\w+_)(\d)\.\.(\d)', names[0])
    if ranged:
        names = [f'{ranged[1]}{i}' for i in range(int(ranged[2]), int(ranged[3]) + 1)]
    if header == 'setting' and not names[0].startswith(SENSOR_PREFIX):
        return [(f'{SENSOR_PREFIX}{topic}.{names[0]}', 0, 1) for topic in SENSOR_TOPICS]
    return [(name, i, len(names)) for i, name in enumerate(names)]


def unit_of(text):
    text = re.sub(r'\s*\((gauge|absolute)\)|,\s*absolute|\s*\(integer\)', '', text).strip()
    text = text.replace('³', '^3').replace('·', '*')
    return '1' if text in ('–', '-', '') else text


def symbol_of(text):
    for greek, latin in GREEK.items():
        text = text.replace(greek, latin)
    return '' if text == '–' else text


def numbers(text):
    """Return the numbers a cell prints before any '(': '1.667e-3 (100 L/min)' -> ['1.667e-3']."""
    text = text.replace('−', '-').replace('`', '')
    return re.findall(r'(?<![\w.])-?\d+(?:\.\d*)?(?:e[-+]?\d+)?', text.split('(')[0])


def agrees(printed, value):
    """Whether value rounds to printed (a number as a table prints it)."""
    try:
        exponent = Decimal(printed).as_tuple().exponent
    except InvalidOperation:
        return False
    return abs(float(printed) - value) <= 0.5 * 10.0 ** exponent * (1 + 1e-9)


def reference_defaults():
    loaded = load_parameters()
    return {**loaded.params, **loaded.settings}


def documented_rows():
    for page in PAGES:
        for place, header, first, columns in parameter_tables(page):
            for name, index, count in names_of(first, header):
                yield place, name, index, count, columns


def row_problems(place, name, index, count, columns, defaults):
    """Return the disagreements of one documented name with the catalogue, as text."""
    if name not in CATALOGUE:
        return [] if name in OUTSIDE else [f'{place}: {name} is not in the catalogue']
    spec, problems = CATALOGUE[name], []
    if 'symbol' in columns:
        symbol = symbol_of(columns['symbol'].split('..')[0])
        if count > 1:  # K_1..K_3: the row's i-th symbol
            symbol = symbol[:-1] + name[-1]
        if symbol != spec.symbol:
            problems.append(f'{place}: {name} symbol {symbol!r}, catalogue {spec.symbol!r}')
    if 'unit' in columns and unit_of(columns['unit']) != spec.unit:
        problems.append(f'{place}: {name} unit {columns["unit"]!r}, catalogue {spec.unit!r}')
    if columns.get('limits') and spec.minimum is not None:
        low, high = (float(n) for n in numbers(columns['limits'].replace('…', ' ')))
        if (low, high) != (spec.minimum, spec.maximum):
            problems.append(f'{place}: {name} limits {low:g} … {high:g}, catalogue '
                            f'{spec.minimum:g} … {spec.maximum:g}')
    if 'default' in columns:
        problems += default_problems(place, name, index, count, columns, defaults)
    return problems


def default_problems(place, name, index, count, columns, defaults):
    """Return the disagreements of a documented default (and its unit, if it gives one)."""
    spec, text = CATALOGUE[name], columns['default']
    default = defaults.get(name, spec.default)
    if place.startswith('analyser.md'):
        default = {s.name: s.default for s in ANALYSER_DOUBLES}[name]
    if default is None:  # computed: preset_pressure is the cracking pressure
        return [] if 'cracking pressure' in text else [
            f'{place}: {name} default {text!r}, catalogue: the cracking pressure']
    if isinstance(default, bool) or spec.kind == 'bool':
        return [] if text.strip('`') == str(default).lower() else [
            f'{place}: {name} default {text!r}, catalogue {default}']
    printed = numbers(text)
    if len(printed) != count or not agrees(printed[index], default):
        return [f'{place}: {name} default {text!r}, catalogue {default!r}']
    unit = text.split('(')[0].replace(printed[index], '', 1).strip()
    if 'unit' not in columns and unit and unit_of(unit) != spec.unit:
        return [f'{place}: {name} default in {unit!r}, catalogue {spec.unit!r}']
    return []


def test_the_docs_tables_agree_with_the_catalogue():
    defaults = reference_defaults()
    problems = []
    for place, name, index, count, columns in documented_rows():
        problems += row_problems(place, name, index, count, columns, defaults)
    assert not problems, '\n'.join(problems)


def test_every_catalogue_entry_is_documented_in_a_table():
    documented = {name for _, name, _, _, _ in documented_rows()}
    text = ''.join((DOCS / page).read_text(encoding='utf-8') for page in PAGES)
    missing = [
        name for name, spec in CATALOGUE.items()
        if name not in documented and not (spec.kind == 'string' and f'`{name}`' in text)
    ]
    assert not missing, f'in no parameter table of docs/{", docs/".join(PAGES)}: {missing}'


def test_the_table_reader_finds_the_tables_and_a_drift():
    rows = list(documented_rows())
    pages = {place.split(':')[0] for place, *_ in rows}
    assert pages == set(PAGES)
    place, name, index, count, columns = next(
        r for r in rows if r[1] == 'burst_pressure' and 'default' in r[4]
    )
    assert not row_problems(place, name, index, count, columns, reference_defaults())
    wrong = {**columns, 'default': '36e6', 'unit': 'kPa', 'symbol': 'p_b'}
    assert len(row_problems(place, name, index, count, wrong, reference_defaults())) == 3


def test_catalogue_entries_are_complete_and_within_their_limits():
    for name, spec in CATALOGUE.items():
        assert spec.name == name and spec.unit and spec.description and spec.source, name
        assert spec.kind in ('double', 'bool', 'integer', 'string'), name
        if spec.kind in ('double', 'integer'):
            assert spec.symbol and spec.minimum < spec.maximum, name
            if spec.default is not None:
                assert spec.minimum <= spec.default <= spec.maximum, name
    for name, value in reference_defaults().items():
        assert CATALOGUE[name].minimum <= value <= CATALOGUE[name].maximum, name


def test_sensor_topics_are_the_models_pressures():
    assert SENSOR_TOPICS == STATE_NAMES[P_S:P_C + 1]
    assert [s.name for s in SENSOR_SETTINGS][:3] == ['bandwidth', 'bias', 'noise_std']


def test_split_sorts_a_change_by_section():
    change = split({
        'main_valve_mass': 0.07, 'm_p': 0.01, 'step_size': 1e-5, 'preset_pressure': 7e6,
        'fault.main_valve_stuck': True, 'fault.unknown': 1.0, 'sensor.noise_seed': 3,
        'fault_schedule': 'f.yaml', 'flush_interval': 1.0,
    })
    assert change.model == {'main_valve_mass': 0.07}
    assert change.other == {'m_p': 0.01}  # a symbol: the loader resolves it
    assert change.setting == {'step_size': 1e-5} and change.preset == {'preset_pressure': 7e6}
    assert change.fault == {'fault.main_valve_stuck': True, 'fault.unknown': 1.0}
    assert list(change.injection) == [
        'fault.main_valve_stuck', 'fault.unknown', 'sensor.noise_seed', 'fault_schedule'
    ]
    assert change.analyser == {'flush_interval': 1.0}


@pytest.mark.parametrize('name', ['initial_inlet_flow', 'flush_interval', 'ambient_pressure'])
def test_live_names_are_the_retunable_ones(name):
    assert (name in LIVE_NAMES) == (name == 'ambient_pressure')
