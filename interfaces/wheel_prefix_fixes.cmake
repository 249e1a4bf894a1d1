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

# Included into the vendored simulation_interfaces project (CMAKE_PROJECT_INCLUDE) when it
# builds against the ROS 2 wheels of PyPI, not against a ROS install. The wheels' exported
# targets name the Python include folder of the machine that built them, which does not
# exist here, nor its NumPy's; at the end of the configure step this swaps them for this
# interpreter's.
function(valve_sim_fix_wheel_include_directories)
  find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
  get_directory_property(targets IMPORTED_TARGETS)
  foreach(target IN LISTS targets)
    get_target_property(folders ${target} INTERFACE_INCLUDE_DIRECTORIES)
    if(folders)
      set(kept "")
      foreach(folder IN LISTS folders)
        if(folder MATCHES "^/opt/python/.*/numpy/")
          list(APPEND kept ${Python3_NumPy_INCLUDE_DIRS})
        elseif(folder MATCHES "^/opt/python/")
          list(APPEND kept ${Python3_INCLUDE_DIRS})
        else()
          list(APPEND kept ${folder})
        endif()
      endforeach()
      set_target_properties(${target} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${kept}")
    endif()
  endforeach()
endfunction()
cmake_language(DEFER CALL valve_sim_fix_wheel_include_directories)
