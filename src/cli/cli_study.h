/* The analysis commands of the mrvi tool (cli_study.c). */
#ifndef MRVI_CLI_STUDY_H
#define MRVI_CLI_STUDY_H

extern const char mrvi_usage_converge[];
extern const char mrvi_usage_stability[];
extern const char mrvi_usage_timing[];

/* argv[0] is the command name; return the process exit status. */
int mrvi_cmd_converge(int argc, char **argv);
int mrvi_cmd_stability(int argc, char **argv);
int mrvi_cmd_timing(int argc, char **argv);

#endif
