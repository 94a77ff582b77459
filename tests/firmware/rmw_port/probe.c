#include "agent_port_check.h"
int agent_port_probe;
