/* mrvi export and the XDMF file of mrvi run (cli_export.c). */
#ifndef MRVI_CLI_EXPORT_H
#define MRVI_CLI_EXPORT_H

#include <stddef.h>

extern const char mrvi_usage_export[];

/* argv[0] is the command name; return the process exit status. */
int mrvi_cmd_export(int argc, char **argv);

/* path with a trailing ".h5" replaced by ext (or ext appended) into buf. */
void mrvi_cli_replace_extension(const char *path, const char *ext, char *buf,
                                size_t len);

/* Write OUT.xdmf beside the run file OUT.h5 (a line in the summary unless
 * quiet; a warning on stderr when it cannot be written, or when OUT.xdmf
 * is a file mrvi did not write and force is 0).  0 or -1. */
int mrvi_cli_write_xdmf(const char *h5_path, int quiet, int force);

#endif
