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
The `valve-sim` command line: the entry (cli) and one module per subcommand.

Each subcommand module has add_arguments(parser) and run(args) -> exit code: it parses,
calls the library and prints; options declares the options several of them take and
reads them (the model's, the studies', a bag's signals). A subcommand's module level
loads no numba, scipy, matplotlib, dask or rclpy (run() does), so that
`valve-sim CMD --help` is quick.
May import: valve_sim.core, fmu, analysis, recording and ros, and commands.options; no
subcommand imports another (cli, the entry point, finds them by name), no module
imports rclpy (ros/ drives the nodes: demo through ros.demo_driver).
"""
