/* libFuzzer target: the description-file loader with overrides.
 *
 * The input is the description text; every line that starts with
 * "# set: " (the convention of tests/bad_input/) also becomes one --set
 * override, so the seeds in systems/ and tests/bad_input/ carry theirs.
 * The description is read up to its first NUL byte (as a string).  Any
 * crash, sanitizer report, leak or timeout is a finding; a rejected input
 * is not. */
#include "mrvi.h"

#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define MAX_OVERRIDES 16

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  char *text = malloc(size + 1);
  if (!text)
    return 0;
  memcpy(text, data, size);
  text[size] = '\0';
  /* Overrides: copies of the "# set: " lines, up to their newline. */
  char *ov[MAX_OVERRIDES];
  int n_ov = 0;
  for (char *line = text; line && n_ov < MAX_OVERRIDES;) {
    char *nl = strchr(line, '\n');
    size_t len = nl ? (size_t)(nl - line) : strlen(line);
    if (len >= 7 && !strncmp(line, "# set: ", 7)) {
      ov[n_ov] = malloc(len - 6);
      if (!ov[n_ov])
        break;
      memcpy(ov[n_ov], line + 7, len - 7);
      ov[n_ov][len - 7] = '\0';
      n_ov++;
    }
    line = nl ? nl + 1 : NULL;
  }
  char msg[1024];
  mrvi_system *sys = NULL;
  int st = mrvi_system_load_string(text, "fuzz.yaml", (const char *const *)ov,
                                   n_ov, &sys, msg, sizeof msg);
  /* The contract: a system on success, none and a message on failure. */
  if ((st == MRVI_OK) != (sys != NULL) || (st != MRVI_OK && !msg[0]))
    abort();
  mrvi_system_free(sys);
  for (int i = 0; i < n_ov; i++)
    free(ov[i]);
  free(text);
  return 0;
}
