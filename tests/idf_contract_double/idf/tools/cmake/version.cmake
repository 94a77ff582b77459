# contract double: stands in for ESP-IDF v5.3.5's tools/cmake/version.cmake (the version numbers
# the double's idf.py reports), because ESP-IDF cannot be fetched here.
set(IDF_VERSION_MAJOR 5)
set(IDF_VERSION_MINOR 3)
set(IDF_VERSION_PATCH 5)
set(ENV{IDF_VERSION} "${IDF_VERSION_MAJOR}.${IDF_VERSION_MINOR}.${IDF_VERSION_PATCH}")
