// Negative control for check_core_includes.sh: the core must not depend on the evaluation,
// so a core file that includes one of its headers must be rejected.
#include "dynamic_occupancy_grid/evaluation/simulator.h"
