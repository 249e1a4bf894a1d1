#!/usr/bin/env bash
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
#
# Attack valve_node and the tools with every class of hostile input of issue 25 and
# report what survived (bench/attack.py says what it applies).
#
#     bench/attack.sh [--json FILE]      (default out/attack.json)
#
# Uses the worktree's .venv (python3 run.py test creates it). One line per attack,
# then the count of attacks survived and the run time; exit code 0 only if all survived.
set -euo pipefail
cd "$(dirname "$0")/.."
[ -x .venv/bin/python ] || python3 run.py test test/lint/test_layering.py -q > /dev/null
exec .venv/bin/python bench/attack.py "$@"
