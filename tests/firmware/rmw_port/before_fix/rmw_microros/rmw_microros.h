/* The shape of rmw_microxrcedds_c/include/rmw_microros/rmw_microros.h at bc4eb312 (before #315):
 * the port buffer holds 4 characters and a NUL. Only what agent_port_check.h reads. */
#pragma once
#define RMW_UXRCE_TRANSPORT_UDP
#define MAX_IP_LEN 16
#define MAX_PORT_LEN 5
typedef struct rmw_uxrce_transport_params_t {
    char agent_address[MAX_IP_LEN];
    char agent_port[MAX_PORT_LEN];
    unsigned client_key;
} rmw_uxrce_transport_params_t;
