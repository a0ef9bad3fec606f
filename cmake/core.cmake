# The ROS-free libraries, shared by the catkin build (CMakeLists.txt) and the plain CMake
# build that proves the split (test/core_standalone):
#   dynamic_occupancy_grid_core        the mapping library a user links (Eigen; zlib for the
#                                      model file's CRC-32)
#   dynamic_occupancy_grid_evaluation  the simulator and the papers' experiments, on top of
#                                      the core; the core never depends on it
find_package(Eigen3 3.3 REQUIRED NO_MODULE)
find_package(Threads REQUIRED)
find_package(ZLIB REQUIRED)

set(DOG_ROOT ${CMAKE_CURRENT_LIST_DIR}/..)
add_library(dynamic_occupancy_grid_core
  # the cell and its learning
  ${DOG_ROOT}/src/core/cell/cell_model.cpp
  ${DOG_ROOT}/src/core/cell/online_em.cpp
  ${DOG_ROOT}/src/core/cell/cell_kinds.cpp
  ${DOG_ROOT}/src/core/cell/offline_em.cpp
  ${DOG_ROOT}/src/core/cell/mrf.cpp
  # the grid and a scan's way into it
  ${DOG_ROOT}/src/core/grid/cell_grid.cpp
  ${DOG_ROOT}/src/core/grid/scan_beams.cpp
  ${DOG_ROOT}/src/core/grid/step_clock.cpp
  ${DOG_ROOT}/src/core/grid/mapper.cpp
  ${DOG_ROOT}/src/core/memory/memory_model.cpp
  # the laser's pose when tf cannot be trusted: odometry, particles whose maps are cell HMMs
  ${DOG_ROOT}/src/core/pose/motion_model.cpp
  ${DOG_ROOT}/src/core/pose/resampling.cpp
  ${DOG_ROOT}/src/core/pose/particle_map.cpp
  ${DOG_ROOT}/src/core/pose/pose_filter.cpp
  ${DOG_ROOT}/src/core/pose/corrected_mapping.cpp
  # what leaves the map: layers and files (file_io: regular files only, atomic writes)
  ${DOG_ROOT}/src/core/layers/file_io.cpp
  ${DOG_ROOT}/src/core/layers/layers.cpp
  ${DOG_ROOT}/src/core/layers/map_export.cpp
  ${DOG_ROOT}/src/core/layers/model_io.cpp
)
target_include_directories(dynamic_occupancy_grid_core PUBLIC ${DOG_ROOT}/include)
target_link_libraries(dynamic_occupancy_grid_core PUBLIC Eigen3::Eigen Threads::Threads)
# Only model_io.cpp includes zlib.h; no public header does, so users need not see it.
target_link_libraries(dynamic_occupancy_grid_core PRIVATE ZLIB::ZLIB)
target_compile_features(dynamic_occupancy_grid_core PUBLIC cxx_std_17)
# -fno-semantic-interposition: the library's calls to its own functions may be inlined (with
# -fPIC, GCC otherwise calls each through the PLT, in case another library interposes it;
# the scan's per-cell visitor was such a call). Nobody interposes functions of this library.
target_compile_options(dynamic_occupancy_grid_core PRIVATE -Wall -Wextra -Wpedantic -fno-semantic-interposition)
set_target_properties(dynamic_occupancy_grid_core PROPERTIES POSITION_INDEPENDENT_CODE ON)

add_library(dynamic_occupancy_grid_evaluation
  ${DOG_ROOT}/src/evaluation/simulator.cpp
  ${DOG_ROOT}/src/evaluation/evaluation.cpp
  ${DOG_ROOT}/src/evaluation/planner.cpp
  ${DOG_ROOT}/src/evaluation/path_planning.cpp
  ${DOG_ROOT}/src/evaluation/memory_experiment.cpp
  ${DOG_ROOT}/src/evaluation/mrf_experiment.cpp
  ${DOG_ROOT}/src/evaluation/learning_experiment.cpp
  ${DOG_ROOT}/src/evaluation/murphy_corridor.cpp
  ${DOG_ROOT}/src/evaluation/murphy_doors.cpp
  ${DOG_ROOT}/src/evaluation/pose_correction.cpp
  ${DOG_ROOT}/src/evaluation/murphy_corridor_report.cpp
  ${DOG_ROOT}/src/evaluation/prediction_check.cpp
)
target_link_libraries(dynamic_occupancy_grid_evaluation PUBLIC dynamic_occupancy_grid_core)
target_compile_options(dynamic_occupancy_grid_evaluation PRIVATE -Wall -Wextra -Wpedantic)
set_target_properties(dynamic_occupancy_grid_evaluation PROPERTIES POSITION_INDEPENDENT_CODE ON)
