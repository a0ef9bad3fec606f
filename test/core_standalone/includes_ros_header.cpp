// Negative control for check_core_includes.sh: this file includes a ROS header (directly
// and through a standard one), so the audit must reject it.
#include <vector>

#include <ros/time.h>
