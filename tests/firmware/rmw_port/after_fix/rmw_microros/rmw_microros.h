/* A port buffer that holds "65535" and its NUL, as any fix of rmw_microxrcedds#314 needs. */
#pragma once
#define RMW_UXRCE_TRANSPORT_UDP
#define MAX_IP_LEN 16
#define MAX_PORT_LEN 5
typedef struct rmw_uxrce_transport_params_t {
    char agent_address[MAX_IP_LEN];
    char agent_port[MAX_PORT_LEN + 1];
    unsigned client_key;
} rmw_uxrce_transport_params_t;
