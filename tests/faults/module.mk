# tests/faults/module.mk - the fault-injection shim (tests/faults/faultinject.c, preloaded by
# tests/test_faults.c; docs/reliability.md) and plcrash.c (PLplot's plinit crashing). Built
# without sanitizers (the shim forwards to ASan's allocator in an ASan build) next to the test
# binary, which finds them beside $(BIN).
#   make faults   the sweep of every failure point of run, export and delight import (every
#                 FAULT_MALLOC_STEP-th allocation; in the run scenarios every
#                 FAULT_RUN_MALLOC_STEP-th allocation and FAULT_RUN_WRITE_STEP-th write if set;
#                 1, the default, is every one: days for run) on FAULT_JOBS workers with the gcc
#                 ASan+UBSan build; the counts in build/asan/faults.md
#   make faults FAULT_SWEEP=sites   the same, but the allocations fail once for each distinct
#                 stack they are made from (at its first call) instead of at every n
#   make faults FAULT_POINTS=A-B   only the points A..B of each scenario's list (a sweep too long
#                 for one sitting in parts, with the same binaries; the report says which)
FAULT_SHIM := $(BUILD)/tests/faults/faultinject.so
$(FAULT_SHIM): tests/faults/faultinject.c
	@mkdir -p $(dir $@)
	gcc -std=gnu11 -Wall -Wextra -Werror -O1 -g -fno-omit-frame-pointer -shared -fPIC $< -ldl -o $@
PLCRASH_SHIM := $(BUILD)/tests/faults/plcrash.so
$(PLCRASH_SHIM): tests/faults/plcrash.c
	@mkdir -p $(dir $@)
	gcc -std=gnu11 -Wall -Wextra -Werror -O1 -g -shared -fPIC $< -ldl -o $@
test-build: $(FAULT_SHIM) $(PLCRASH_SHIM)

FAULT_SWEEP ?= full
FAULT_MALLOC_STEP ?= 1
FAULT_RUN_MALLOC_STEP ?=
FAULT_RUN_WRITE_STEP ?=
FAULT_JOBS ?= 1
FAULT_POINTS ?=
.PHONY: faults faults-run
faults: deps
	$(MAKE) --no-print-directory BUILD=build/asan SAN=1 faults-run
faults-run: $(TEST_BIN) $(BIN) $(FAULT_SHIM)
	@echo '| scenario | malloc calls | tried | write calls | tried | fsync calls | rename calls | injected runs | failed cleanly | succeeded complete | bad |' > $(BUILD)/faults.md
	@echo '| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |' >> $(BUILD)/faults.md
	GS_SHARED=$(SHARED) GS_BIN=$(BIN) GS_SAN=$(SAN) GS_FAULT_SWEEP=$(FAULT_SWEEP) GS_FAULT_MALLOC_STEP=$(FAULT_MALLOC_STEP) \
	GS_FAULT_RUN_MALLOC_STEP=$(FAULT_RUN_MALLOC_STEP) GS_FAULT_RUN_WRITE_STEP=$(FAULT_RUN_WRITE_STEP) GS_FAULT_JOBS=$(FAULT_JOBS) GS_FAULT_POINTS=$(FAULT_POINTS) GS_FAULT_REPORT=$(CURDIR)/$(BUILD)/faults.md \
	GS_TEST_TIMEOUT_S=172800 GS_TEST_JOBS=1 LSAN_OPTIONS=suppressions=$(CURDIR)/tests/lsan.supp:print_suppressions=0 \
	  $(TEST_BIN) fault_injection_ _fault_injection_run_new_database
	@cat $(BUILD)/faults.md

# make kills KILLS=N: N random SIGKILLs of `gridsurvey run` over its whole duration, each
# resumed and compared (tests/test_pipeline.c, pipeline_sigkill_campaign; docs/reliability.md)
KILLS ?= 100
.PHONY: kills
kills: $(TEST_BIN) $(BIN)
	GS_SHARED=$(SHARED) GS_BIN=$(BIN) GS_SAN=$(SAN) GS_KILLS=$(KILLS) GS_TEST_TIMEOUT_S=86400 \
	LSAN_OPTIONS=suppressions=$(CURDIR)/tests/lsan.supp:print_suppressions=0 $(TEST_BIN) _pipeline_sigkill_campaign
