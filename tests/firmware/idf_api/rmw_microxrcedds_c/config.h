/* Test double of the generated rmw_microxrcedds_c/config.h: the library's transport. */
#pragma once
#ifdef TEST_LIBRARY_CUSTOM
#define RMW_UXRCE_TRANSPORT_CUSTOM
#else
#define RMW_UXRCE_TRANSPORT_UDP
#endif
