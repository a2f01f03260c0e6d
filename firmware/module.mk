# firmware/module.mk - the ACam controller firmware (avr-gcc, Debian gcc-avr + avr-libc) and
# the wiring of its simavr tests into build/run_tests (included by the top-level Makefile).
#   make firmware     $(BUILD)/firmware/acam.elf and acam.hex (flash: docs/firmware.md)
# tests/test_firmware.c runs the ELF in libsimavr; it finds it through GS_FIRMWARE_ELF (set by
# `make test`) or the path compiled in below.
AVR_CC := avr-gcc
AVR_OBJCOPY := avr-objcopy
AVR_SIZE := avr-size
FW_DIR := $(BUILD)/firmware
FW_SRCS := firmware/main.c firmware/schedule.c firmware/proto.c
FW_OBJS := $(patsubst firmware/%.c,$(FW_DIR)/%.o,$(FW_SRCS))
FW_ELF := $(FW_DIR)/acam.elf
FW_HEX := $(FW_DIR)/acam.hex
# As strict as avr-gcc 5.4 allows: the host warning set, C11. avr_mcu_section.h (simavr) puts
# the chip name and clock in a .mmcu section of the ELF only; the HEX leaves it out.
AVR_CFLAGS := -mmcu=atmega328p -DF_CPU=16000000UL -O2 -g -std=c11 $(WARN) \
	-ffunction-sections -fdata-sections -I. -isystem /usr/include/simavr/avr -MMD -MP
AVR_LDFLAGS := -mmcu=atmega328p -Wl,--gc-sections \
	-Wl,--undefined=_mmcu,--section-start=.mmcu=0x910000

.PHONY: firmware
firmware: $(FW_ELF) $(FW_HEX)

$(FW_DIR)/%.o: firmware/%.c firmware/module.mk
	@mkdir -p $(dir $@)
	$(AVR_CC) $(AVR_CFLAGS) -c $< -o $@
$(FW_ELF): $(FW_OBJS)
	$(AVR_CC) $(AVR_LDFLAGS) $^ -o $@
	@$(AVR_SIZE) $@
$(FW_HEX): $(FW_ELF)
	$(AVR_OBJCOPY) -O ihex -j .text -j .data $< $@

# Host side: the simavr harness (tests/test_firmware.c) and the firmware logic compiled natively
# (tests/test_firmware_logic.c includes firmware/*.c). simavr's headers are not -Wpedantic
# clean, hence -isystem.
$(BUILD)/tests/test_firmware.o: CPPFLAGS += -isystem /usr/include/simavr \
	-DGS_FIRMWARE_ELF_DEFAULT='"$(FW_ELF)"'
$(TEST_BIN): LDLIBS += -lsimavr -lelf
# the tests load the ELF at run time (order-only: it is not linked in)
$(TEST_BIN): | $(FW_ELF)
test-build: $(FW_ELF)
test: export GS_FIRMWARE_ELF = $(FW_ELF)

-include $(FW_OBJS:.o=.d)
