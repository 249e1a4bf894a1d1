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
Many step tests: the paper's parameter study, tolerance and sensitivity studies.

Lives here: cases (the study's cases and the protocol that sets each preset: StudyCase),
runner (batches of cases on a backend, rows streamed to a results file, resume),
backend (where batches run: here, a process pool or Dask, sized for this machine;
it receives cases, it builds none), results (the results file, fingerprints),
tolerances (Monte Carlo of manufacturing tolerances), sensitivity (Sobol indices),
plots (the study's and the tolerance study's figures).
May import: valve_sim.core, valve_sim.analysis.paper, the steps room and plotting.
"""
