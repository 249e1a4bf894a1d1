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
The optional features and the extra of setup.py that brings each: one line when missing.

    pip install -e '.[fmu]'      (from valve_sim's source; or the packages EXTRAS names)

require() imports a feature's modules and raises one line (MissingExtraError, or the
caller's error class) naming the feature, the extra and the packages to install,
never an ImportError traceback.
"""

from importlib import import_module

from valve_sim.core.errors import MissingExtraError

EXTRAS = {  # extra: its packages, as setup.py lists them
    'studies': "'dask[distributed]' SALib 'pymoo>=0.6.2,<0.7'",
    'foxglove': 'foxglove-sdk',
    'fmu': "'pythonfmu>=0.7,<0.8' fmpy",
}


def require(feature, extra, *modules, error=MissingExtraError):
    """Import modules for feature; error naming the extra if one cannot be imported."""
    for module in modules:
        try:
            import_module(module)
        except ImportError as missing:
            raise error(
                f"{feature} needs the '{extra}' extra, and {missing.name or module} is not "
                f"installed: pip install {EXTRAS[extra]} (or pip install -e '.[{extra}]' in "
                "valve_sim's source)"
            ) from None
