# contract double: stands in for micro_ros_espidf_component's libmicroros.mk (jazzy), because
# the micro-ROS sources and the ESP-IDF cross compilers cannot be fetched here.
#
# Same interface as upstream: run from the component dir as
#   make -f libmicroros.mk X_CC=... X_AR=... X_CXX=... C_STANDARD=17 MIDDLEWARE=microxrcedds \
#        BUILD_DIR=<app build dir> IDF_INCLUDES=... IDF_PATH=... IDF_TARGET=<chip> \
#        APP_COLCON_META=<app>/app-colcon.meta EXTRA_ROS_PACKAGES=<dir>
# and the same outputs: libmicroros.a and include/<pkg>/<pkg>/... in the component dir.
# Like upstream every target is a plain file or directory, so once libmicroros.a exists
# nothing is rebuilt (changed packages or metas need `make -f libmicroros.mk clean`).
#
# Instead of cross-compiling the micro-ROS stack, it clones two repositories of standard
# interfaces (git on PATH may be espdock's pinned git), generates rosidl-shaped C
# headers and typesupport sources for the standard interfaces it cloned and every
# package under EXTRA_ROS_PACKAGES, compiles them with X_CC (the host gcc here) and merges the
# objects as upstream does (`ar x` each package archive, prefix, `ar rc -s`).

EXTENSIONS_DIR := $(shell pwd)
UROS_DIR := $(EXTENSIONS_DIR)/micro_ros_src
BUILD_DIR ?= $(EXTENSIONS_DIR)/build
X_CC ?= gcc
X_AR ?= ar
C_STANDARD ?= 17
MIDDLEWARE ?= microxrcedds
IDF_TARGET ?= esp32
APP_COLCON_META ?=
EXTRA_ROS_PACKAGES ?= $(EXTENSIONS_DIR)/extra_packages
PYTHON ?= python3

.PHONY: all clean

all: $(EXTENSIONS_DIR)/libmicroros.a

# The workspace sources, cloned like upstream's at the head of branch jazzy (here from the
# double's own repositories), plus the extra packages (upstream copies EXTRA_ROS_PACKAGES to
# src/extra_packages the same way).
DOUBLE_REPOS ?= file:///opt/espdock-double/repos
$(UROS_DIR)/src:
	rm -rf $(UROS_DIR); mkdir -p $(UROS_DIR)/src.tmp
	git clone -b jazzy $(DOUBLE_REPOS)/common_interfaces.git $(UROS_DIR)/src.tmp/common_interfaces
	git clone -b jazzy $(DOUBLE_REPOS)/rcl_interfaces.git $(UROS_DIR)/src.tmp/rcl_interfaces
	if [ -d "$(EXTRA_ROS_PACKAGES)" ]; then cp -RL "$(EXTRA_ROS_PACKAGES)" $(UROS_DIR)/src.tmp/extra_packages; fi
	mv $(UROS_DIR)/src.tmp $(UROS_DIR)/src

# The "colcon build": generate, compile every package into its own archive, check that every
# installed header compiles. Built in install.tmp and renamed, so a failure leaves no install.
$(UROS_DIR)/install: $(UROS_DIR)/src
	@if [ "$(MIDDLEWARE)" != "microxrcedds" ]; then \
	  echo "micro-ROS double: only MIDDLEWARE=microxrcedds is modelled, not '$(MIDDLEWARE)'" >&2; exit 1; fi
	rm -rf $(UROS_DIR)/install.tmp $(UROS_DIR)/gen
	$(PYTHON) $(EXTENSIONS_DIR)/double/generate.py --src $(UROS_DIR)/src \
	  --headers $(EXTENSIONS_DIR)/double/headers --out $(UROS_DIR)/install.tmp --gen $(UROS_DIR)/gen \
	  --colcon-meta $(EXTENSIONS_DIR)/colcon.meta --app-colcon-meta "$(APP_COLCON_META)" \
	  --target $(IDF_TARGET) --middleware $(MIDDLEWARE) --sdkconfig-h "$(BUILD_DIR)/config/sdkconfig.h" \
	  --path-map "$(UROS_DIR)/src/extra_packages=$(EXTRA_ROS_PACKAGES)"
	set -e; inc="-I$(UROS_DIR)/install.tmp/include"; \
	for d in $(UROS_DIR)/install.tmp/include/*/; do inc="$$inc -I$$d"; done; \
	$(X_CC) -std=c$(C_STANDARD) -Wall -fsyntax-only $$inc $(UROS_DIR)/gen/all_headers.c; \
	mkdir -p $(UROS_DIR)/install.tmp/lib; \
	for pkg in $(UROS_DIR)/gen/*/; do \
	  name=$$(basename $$pkg); objs=""; \
	  for src in $$pkg*.c; do \
	    $(X_CC) -std=c$(C_STANDARD) -Wall -O2 -ffunction-sections -fdata-sections $$inc -c $$src -o $$src.obj; \
	    objs="$$objs $$src.obj"; \
	  done; \
	  rm -f $(UROS_DIR)/install.tmp/lib/lib$$name.a; \
	  $(X_AR) rc $(UROS_DIR)/install.tmp/lib/lib$$name.a $$objs; \
	done
	mv $(UROS_DIR)/install.tmp $(UROS_DIR)/install

$(EXTENSIONS_DIR)/libmicroros.a: $(UROS_DIR)/install
	set -e; rm -rf $(UROS_DIR)/libmicroros; mkdir -p $(UROS_DIR)/libmicroros; cd $(UROS_DIR)/libmicroros; \
	for file in $$(find $(UROS_DIR)/install/lib/ -name '*.a' | LC_ALL=C sort); do \
	  folder=$$(basename $$file .a); \
	  mkdir -p $$folder; cd $$folder; $(X_AR) x $$file; \
	  for f in *; do mv $$f ../$$folder-$$f; done; \
	  cd ..; rm -rf $$folder; \
	done; \
	rm -f libmicroros.a; $(X_AR) rc -s libmicroros.a $$(ls *.obj | LC_ALL=C sort); \
	cp libmicroros.a $(EXTENSIONS_DIR)/libmicroros.a.tmp; \
	cd ..; rm -rf libmicroros; \
	rm -rf $(EXTENSIONS_DIR)/include; cp -R $(UROS_DIR)/install/include $(EXTENSIONS_DIR)/include; \
	mv $(EXTENSIONS_DIR)/libmicroros.a.tmp $(EXTENSIONS_DIR)/libmicroros.a

clean:
	rm -rf $(EXTENSIONS_DIR)/libmicroros.a $(EXTENSIONS_DIR)/libmicroros.a.tmp $(EXTENSIONS_DIR)/include \
	  $(UROS_DIR)
