# gridsurvey - GNU make, one out-of-tree build folder ($(BUILD)).
#   make          build the gridsurvey binary
#   make check    install missing Debian packages, build, run every test (plain, gcc and clang
#                 ASan+UBSan)
#   make demo     install, build, run the main job on the built-in scene
#   make demo-transport  the light-transport lab (unmix, render, relight, separate)
#   make bench    performance tables (docs/bench-*.md, docs/accuracy.md)
BUILD ?= build
SAN ?=
CC := gcc
CXX := g++
PKGS := sqlite3 fftw3 fftw3l sndfile jansson plplot spng nettle lapacke libtiff-4 geos libpq
WARN := -Wall -Wextra -Wpedantic -Wshadow -Werror
OPT := -O2 -g
SANFLAGS :=
ifeq ($(SAN),1)
SANFLAGS := -fsanitize=address,undefined -fno-sanitize-recover=all
OPT := -O1 -g -fno-omit-frame-pointer $(SANFLAGS)
endif
# clang's UBSan also has what gcc's lacks (float-cast-overflow, pointer-overflow: #16);
# SAN=fuzz adds the coverage libFuzzer needs (tests/fuzz/module.mk)
ifneq ($(filter clang fuzz,$(SAN)),)
CC := clang
CXX := clang++
SANFLAGS := -fsanitize=address,undefined,float-cast-overflow,pointer-overflow -fno-sanitize-recover=all
# (no contraction into fused multiply-adds, as gcc's -std=c11: the same sums in every clone)
OPT := -O1 -g -fno-omit-frame-pointer -ffp-contract=off $(SANFLAGS) $(if $(filter fuzz,$(SAN)),-fsanitize=fuzzer-no-link)
endif
# (the test pass links ASan's runtime as a shared library, as gcc does, so that the fault-injection
# shim, tests/faults/faultinject.c, preloaded, comes before its malloc: docs/reliability.md)
CLANG_SHARED_SAN := $(if $(filter clang,$(SAN)),-shared-libsan -Xlinker -rpath -Xlinker $(shell clang -print-resource-dir 2>/dev/null)/lib/linux)
CPPFLAGS := -D_DEFAULT_SOURCE -I. -MMD -MP
CFLAGS := -std=c11 $(WARN) $(OPT) $(shell pkg-config --cflags $(PKGS) 2>/dev/null)
# (-isystem: the libraries' headers are not ours to warn about; clang -Wpedantic flags OpenCV's)
CXXFLAGS := -std=c++17 $(WARN) $(OPT) $(patsubst -I%,-isystem %,$(shell pkg-config --cflags opencv4 geographiclib 2>/dev/null))
LDFLAGS := $(SANFLAGS) $(CLANG_SHARED_SAN)
# OpenCV: only core and imgproc (PNGs go through libspng; videoio, with its ~180 libraries, is
# in the camera plugin below).
LDLIBS := $(shell pkg-config --libs $(PKGS) 2>/dev/null) -lopencv_imgproc \
	-lopencv_core -lGeographicLib -lopenblas -lcsv -lmvec -lm

# Static libraries in link order (each depends only on those after it): the lowest layer,
# recognize/base (status, format kit, AC/BRF, DELIGHT, capture format), is libbase.a.
MODULES := survey capture recognize gis recognize/base
lib_srcs = $(filter-out survey/main.c,$(wildcard $(1)/*.c $(1)/*.cpp))
lib_objs = $(patsubst %,$(BUILD)/%.o,$(basename $(call lib_srcs,$(1))))
lib_name = $(BUILD)/lib$(notdir $(1)).a
LIBS := $(foreach m,$(MODULES),$(if $(call lib_srcs,$(m)),$(call lib_name,$(m))))
TEST_SRCS := $(wildcard tests/*.c)
TEST_OBJS := $(patsubst %.c,$(BUILD)/%.o,$(TEST_SRCS))
BIN := $(BUILD)/gridsurvey
VIDEOIO := $(dir $(BIN))gridsurvey-videoio.so
TEST_BIN := $(BUILD)/run_tests
DELIGHT_DB := $(BUILD)/delight.sqlite
SHARED ?= ../shared

.PHONY: all deps check test test-build test-asan test-clang demo demo-transport bench clean
all: $(BIN) $(VIDEOIO) $(DELIGHT_DB)

deps:
	@sh .ci/deps.sh

$(BUILD)/%.o: %.c
	@mkdir -p $(dir $@)
	$(CC) $(CPPFLAGS) $(CFLAGS) -c $< -o $@
$(BUILD)/%.o: %.cpp
	@mkdir -p $(dir $@)
	$(CXX) $(CPPFLAGS) $(CXXFLAGS) -c $< -o $@

define lib_rule
$(call lib_name,$(1)): $(call lib_objs,$(1))
	@rm -f $$@
	ar rcs $$@ $$^
endef
$(foreach m,$(MODULES),$(eval $(call lib_rule,$(m))))

# gridsurvey --version names the commit: $(BUILD)/version.h, rewritten only when it changes.
GIT_COMMIT := $(shell git rev-parse --short=12 HEAD 2>/dev/null || echo unknown)$(shell git diff --quiet HEAD 2>/dev/null || echo -dirty)
.PHONY: FORCE
$(BUILD)/version.h: FORCE
	@mkdir -p $(BUILD) && echo '#define GS_GIT_COMMIT "$(GIT_COMMIT)"' > $@.tmp && \
	  (cmp -s $@.tmp $@ && rm -f $@.tmp || mv $@.tmp $@)
$(BUILD)/survey/cli.o: $(BUILD)/version.h
$(BUILD)/survey/cli.o: CPPFLAGS += -I$(BUILD)
# Eq. 7's scores: loops over templates that call log, erfc and exp, which gcc vectorizes with
# glibc's libmvec only without errno (nothing there reads it); the Fourier screens' sqrt likewise
$(BUILD)/recognize/eq7_scores.o $(BUILD)/recognize/eq7_pixscreen.o $(BUILD)/recognize/eq7_bulbscreen.o: CFLAGS += -fno-math-errno
# the continuous templates' and grids' complex products: finite numbers, without C99's recovery
# of a NaN product (the same results for finite operands, no library call per product; gcc's
# flag, which clang 14 does not know)
$(BUILD)/recognize/eq7_matcher.o $(BUILD)/recognize/eq7_sums.o: CFLAGS += $(if $(filter gcc,$(CC)),-fcx-limited-range)

$(BIN): $(BUILD)/survey/main.o $(LIBS)
	$(CXX) $(LDFLAGS) $^ $(LDLIBS) -o $@
$(TEST_BIN): $(TEST_OBJS) $(LIBS)
	$(CXX) $(LDFLAGS) $^ $(LDLIBS) -o $@
# capture/'s hardware backend: libgpiod v1.6 for the binary only (the test binary links
# tests/fake_gpiod.c instead); the camera through opencv_videoio in a plugin beside the binary,
# loaded when a camera is opened (capture/videoio.c: the library and its ~180 dependencies cost
# every process 50 MB and 0.14 s at start); gs_fail, which the plugin calls, is exported to it.
$(BIN): LDLIBS += -lgpiod
$(BIN) $(TEST_BIN): LDFLAGS += -Wl,--export-dynamic-symbol=gs_fail
$(VIDEOIO): capture/videoio/videoio_plugin.cpp capture/internal.h recognize/base/base.h recognize/base/cv_nomem.hpp
	@mkdir -p $(dir $@)
	$(CXX) $(CPPFLAGS) $(CXXFLAGS) -fPIC -shared $< $(LDFLAGS) -lopencv_videoio -lopencv_imgproc -lopencv_core -o $@
$(DELIGHT_DB): $(BIN)
	$(BIN) delight generate -o $@

JOBS := $(shell nproc 2>/dev/null || echo 2)
test-build: $(TEST_BIN) $(BIN) $(VIDEOIO)
test: test-build
	GS_SHARED=$(SHARED) GS_BIN=$(BIN) GS_SAN=$(SAN) \
	LSAN_OPTIONS=suppressions=$(CURDIR)/tests/lsan.supp:print_suppressions=0 $(TEST_BIN)
test-asan:
	$(MAKE) --no-print-directory -j$(JOBS) BUILD=$(BUILD)/asan SAN=1 test-build
	$(MAKE) --no-print-directory BUILD=$(BUILD)/asan SAN=1 test
test-clang:
	$(MAKE) --no-print-directory -j$(JOBS) BUILD=$(BUILD)/clang SAN=clang test-build
	$(MAKE) --no-print-directory BUILD=$(BUILD)/clang SAN=clang test
# The three passes in turn, each built on every CPU and running GS_TEST_JOBS tests at once
# (default: the online CPUs, tests/main.c): as built, gcc ASan+UBSan, clang ASan+UBSan.
check: deps
	$(MAKE) --no-print-directory -j$(JOBS) all test-build
	$(MAKE) --no-print-directory test
	$(MAKE) --no-print-directory test-asan
	$(MAKE) --no-print-directory test-clang
# The whole job on the built-in metropolitan scene (docs/pipeline.md), from scratch each time:
# simulate, recognize, locate, store; phase balance, GeoJSON, PNG map, evaluation vs truth.
# --phases 6: the scene puts 10 % of its districts behind delta-wye transformers (+30 deg).
demo: deps
	$(MAKE) --no-print-directory $(BIN)
	rm -rf $(BUILD)/demo && mkdir -p $(BUILD)/demo
	$(BIN) run capture/scenes/metro.json --phases 6 --db $(BUILD)/demo/survey.sqlite --out-dir $(BUILD)/demo
# Light transport (paper Sec. 5, docs/light-transport.md) on the built-in lab and window scenes:
# unmix (a sources file, then auto), the HDR denoised sequences, relighting as in Fig. 4 and with
# a source switched off (compared with a capture rendered without it), semi-reflection separation.
DT := $(BUILD)/demo-transport
demo-transport: deps
	$(MAKE) --no-print-directory $(BIN)
	rm -rf $(DT) && mkdir -p $(DT)
	$(BIN) simulate capture/scenes/lab_transport.json --out-dir $(DT)/lab --no-progress
	$(BIN) simulate capture/scenes/lab_transport.json --out-dir $(DT)/lab-without-mh70 --drop-light mh70 --no-progress
	$(BIN) unmix $(DT)/lab --sources capture/scenes/lab_transport_sources.json --out-dir $(DT)/unmixed --render
	$(BIN) unmix $(DT)/lab --sources auto --out-dir $(DT)/unmixed-auto
	$(BIN) relight $(DT)/unmixed --set 2=gain:3.5 --set 0=bulb:hps-70w --out-dir $(DT)/relit-fig4
	$(BIN) relight $(DT)/unmixed --set 4=gain:0 --out-dir $(DT)/relit-mh70-off --compare $(DT)/lab-without-mh70
	$(BIN) simulate capture/scenes/window.json --out-dir $(DT)/window --no-progress
	$(BIN) separate $(DT)/window --out-dir $(DT)/separated
	@echo "pictures: $(DT)/unmixed/mean.png, source_NN.png, residual.png, $(DT)/relit-*/preview.png, $(DT)/separated/*.png"
# Performance tables, printed and kept in docs/: Eq. 7 throughput on one core
# (survey/bench.c), the survey database's ingest and query times (survey/bench_db.c), and
# SQLite vs PostGIS on a throw-away cluster (survey/bench_pg.c, tests/pg_cluster.sh).
bench: $(BIN)
	$(BIN) bench recognize --numpy survey/bench_eq7_numpy.py > docs/bench-recognize.md.tmp
	mv docs/bench-recognize.md.tmp docs/bench-recognize.md
	$(BIN) bench db > docs/bench-db.md.tmp
	mv docs/bench-db.md.tmp docs/bench-db.md
	port=$$(PG_FSYNC=on sh tests/pg_cluster.sh start /tmp/gridsurvey-bench-pg.$$$$ $$$$) && \
	  $(BIN) bench pg --pg "host=127.0.0.1 port=$$port user=gs dbname=postgres" > docs/bench-pg.md.tmp; \
	  rc=$$?; sh tests/pg_cluster.sh stop /tmp/gridsurvey-bench-pg.$$$$; [ $$rc -eq 0 ]
	mv docs/bench-pg.md.tmp docs/bench-pg.md
	$(BIN) bench render > docs/bench-render.md.tmp
	mv docs/bench-render.md.tmp docs/bench-render.md
	rm -rf $(BUILD)/bench-metro && $(BIN) simulate capture/scenes/metro.json --out-dir $(BUILD)/bench-metro --no-progress
	$(BIN) bench blobs $(BUILD)/bench-metro > docs/bench-blobs.md.tmp
	mv docs/bench-blobs.md.tmp docs/bench-blobs.md
	$(BIN) bench accuracy --out-dir docs/accuracy
	$(BIN) bench accuracy --drift-sweep --out-dir docs/accuracy-drift
	$(BIN) bench transport > docs/bench-transport.md.tmp
	mv docs/bench-transport.md.tmp docs/bench-transport.md
	@cat docs/bench-recognize.md docs/bench-db.md docs/bench-pg.md docs/bench-render.md docs/bench-blobs.md docs/bench-transport.md
clean:
	rm -rf $(BUILD)

# Module fragments (e.g. firmware/module.mk) add their own targets.
include $(wildcard */module.mk tests/fuzz/module.mk tests/faults/module.mk)

-include $(patsubst %.o,%.d,$(foreach m,$(MODULES),$(call lib_objs,$(m))) $(TEST_OBJS) $(BUILD)/survey/main.o)
