/* `mrvi batch` (cli_batch.c). */
#ifndef MRVI_CLI_BATCH_H
#define MRVI_CLI_BATCH_H

extern const char mrvi_usage_batch[];

/* argv[0] is the command name; return the process exit status. */
int mrvi_cmd_batch(int argc, char **argv);

#endif
