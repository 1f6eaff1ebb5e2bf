/* Helpers shared by the HDF5 readers and the writer (src/io/hdf5_reader.c). */
#ifndef MRVI_H5UTIL_H
#define MRVI_H5UTIL_H

#include <hdf5.h>
#include <stddef.h>

/* Open an mrvi output read-only.  A run killed while writing (SIGKILL,
 * power loss) leaves HDF5's "open for writing" flag set in the file, which
 * a plain open refuses; such a file is opened for SWMR reading, which HDF5
 * allows for a file written in SWMR mode (doc/output.md, "Crash safety").
 * fapl: H5P_DEFAULT or a file access property list. */
hid_t mrvi_h5_open_read(const char *path, hid_t fapl);

/* The root attribute stop_reason of an open mrvi output into buf ("" when
 * absent), variable- or fixed-length.  "running" becomes "incomplete
 * (writer killed)" unless a live run still holds the file's lock (then it
 * stays "running"). */
void mrvi_h5_stop_reason(hid_t file, const char *path, char *buf, size_t len);

#endif
