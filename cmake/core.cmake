# The ROS-free core library, shared by the catkin build (CMakeLists.txt) and the plain
# CMake build that proves the split (test/core_standalone). Eigen (and the
# system's thread library) is its only dependency.
find_package(Eigen3 3.3 REQUIRED NO_MODULE)
find_package(Threads REQUIRED)

set(DOG_ROOT ${CMAKE_CURRENT_LIST_DIR}/..)
add_library(dynamic_occupancy_grid_core
  ${DOG_ROOT}/src/core/cell_grid.cpp
  ${DOG_ROOT}/src/core/cell_model.cpp
  ${DOG_ROOT}/src/core/evaluation.cpp
  ${DOG_ROOT}/src/core/layers.cpp
  ${DOG_ROOT}/src/core/map_export.cpp
  ${DOG_ROOT}/src/core/mapper.cpp
  ${DOG_ROOT}/src/core/memory_experiment.cpp
  ${DOG_ROOT}/src/core/memory_model.cpp
  ${DOG_ROOT}/src/core/model_io.cpp
  ${DOG_ROOT}/src/core/mrf.cpp
  ${DOG_ROOT}/src/core/mrf_experiment.cpp
  ${DOG_ROOT}/src/core/offline_em.cpp
  ${DOG_ROOT}/src/core/online_em.cpp
  ${DOG_ROOT}/src/core/path_planning.cpp
  ${DOG_ROOT}/src/core/planner.cpp
  ${DOG_ROOT}/src/core/prediction_check.cpp
  ${DOG_ROOT}/src/core/scan_beams.cpp
  ${DOG_ROOT}/src/core/simulator.cpp
  ${DOG_ROOT}/src/core/step_clock.cpp
)
target_include_directories(dynamic_occupancy_grid_core PUBLIC ${DOG_ROOT}/include)
target_link_libraries(dynamic_occupancy_grid_core PUBLIC Eigen3::Eigen Threads::Threads)
target_compile_features(dynamic_occupancy_grid_core PUBLIC cxx_std_17)
target_compile_options(dynamic_occupancy_grid_core PRIVATE -Wall -Wextra -Wpedantic)
set_target_properties(dynamic_occupancy_grid_core PROPERTIES POSITION_INDEPENDENT_CODE ON)
