# docs/module.mk - the man page and the bash completion, generated from the --help texts by
# docs/gen-cli-docs.sh (tests/test_cli_docs.c checks the committed ones against the binary),
# and their installation (included by the top-level Makefile).
#   make cli-docs       rewrite docs/gridsurvey.1 and docs/bash-completion/gridsurvey from $(BIN)
#   make install        $(BIN), its camera plugin, the man page and the completion under
#                       $(DESTDIR)$(PREFIX): bin/, lib/gridsurvey/, share/man/man1/,
#                       share/bash-completion/completions/
#   make uninstall      remove those four files
PREFIX ?= /usr/local
INSTALL_FILES := bin/gridsurvey lib/gridsurvey/gridsurvey-videoio.so share/man/man1/gridsurvey.1 share/bash-completion/completions/gridsurvey

.PHONY: cli-docs install uninstall
cli-docs: $(BIN)
	sh docs/gen-cli-docs.sh $(BIN) docs
install: $(BIN) $(VIDEOIO)
	install -d $(DESTDIR)$(PREFIX)/bin $(DESTDIR)$(PREFIX)/lib/gridsurvey \
	  $(DESTDIR)$(PREFIX)/share/man/man1 $(DESTDIR)$(PREFIX)/share/bash-completion/completions
	install -m 755 $(BIN) $(DESTDIR)$(PREFIX)/bin/gridsurvey
	install -m 644 $(VIDEOIO) $(DESTDIR)$(PREFIX)/lib/gridsurvey/gridsurvey-videoio.so
	install -m 644 docs/gridsurvey.1 $(DESTDIR)$(PREFIX)/share/man/man1/gridsurvey.1
	install -m 644 docs/bash-completion/gridsurvey \
	  $(DESTDIR)$(PREFIX)/share/bash-completion/completions/gridsurvey
uninstall:
	rm -f $(addprefix $(DESTDIR)$(PREFIX)/,$(INSTALL_FILES))
