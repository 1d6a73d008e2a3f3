# LaserPi: `make demo` runs the simulated sensor end to end; `make test` runs every test.
# Both install what they need first (tools/bootstrap.sh).
PY := .venv/bin/python

# The fast pipeline's C kernel (device/vision/columns): its unit tests on the host, under
# AddressSanitizer and UndefinedBehaviorSanitizer (any finding fails the run), with the
# -ffp-contract=off that setup.py builds it with.
KERNEL := device/vision/columns
KERNEL_TEST := build/kernel/test_columns
KERNEL_CFLAGS := -std=gnu11 -O1 -g -Wall -Wextra -Werror -ffp-contract=off -fsanitize=address,undefined \
                 -fno-sanitize-recover=all

.PHONY: demo test kernel-test firmware bootstrap clean

bootstrap:
	@./tools/bootstrap.sh

firmware: bootstrap
	@$(MAKE) --no-print-directory -C firmware_pwm

demo: firmware
	@$(PY) -m device.cli demo

test: firmware kernel-test
	@$(PY) -m pytest -q

kernel-test: $(KERNEL_TEST)
	@$(KERNEL_TEST)

$(KERNEL_TEST): $(KERNEL)/test/test_columns.c $(KERNEL)/columns.c $(KERNEL)/columns.h Makefile | bootstrap
	@mkdir -p $(@D)
	gcc $(KERNEL_CFLAGS) -I$(KERNEL) -o $@ $(KERNEL)/test/test_columns.c $(KERNEL)/columns.c -lm

clean:
	rm -rf .venv firmware_pwm/build .pytest_cache build device/vision/_columns*.so
