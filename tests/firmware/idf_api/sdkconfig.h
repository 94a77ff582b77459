/* Test double: the CONFIG_* values come from the compiler's -D options (tests/firmware/CMakeLists.txt). */
