# Exit 0 when the sanitizer report read (a saved stderr) is libhdf5's own:
# in every stack it shows (the access, the allocation of the memory, each
# leak) the first frame outside the sanitizer runtime is in libhdf5.  A
# buffer mrvi passed to HDF5 too small shows mrvi's allocation; UBSan
# reports come from mrvi's code only (libhdf5 is not instrumented).  The
# sanitizer runtime is a shared library with gcc (libsanitizer sources) and
# linked into the program with clang (frames named by the intercepted
# function only: malloc, memcpy, ...; libFuzzer's out-of-memory report
# starts with its own frames).  Used by
# tests/test_hostile_h5.sh and tests/fuzz/run.sh (the list of libhdf5's own
# crashes and why they are listed, not isolated: doc/output.md, "libhdf5's
# own crashes on corrupted files").  A libFuzzer timeout
# report's stack starts with the alarm handler and the C library's signal
# frame: the frame it interrupted is the first after them, so a hang inside
# libhdf5 (its metadata-cache and global-heap retries on a corrupted file,
# as test_hostile_h5.sh already bounds) counts as libhdf5's like its crashes.
/runtime error:/ { ours = 1 }
/AlarmCallback/ { alarm = 1 }
/^ *#[0-9]+ / {
  if (!stack) { stack = 1; decided = 0 }
  if (alarm && !decided && $0 ~ /libc\.so/) next
  if (!decided && $0 !~ /libsanitizer|asan_|__asan|__sanitizer|fuzzer::|interceptor/ &&
      $0 !~ / in (malloc|calloc|realloc|free|posix_memalign|aligned_alloc|mem(cpy|move|set|cmp)|str[a-z]*) /) {
    decided = 1
    if ($0 !~ /libhdf5/) ours = 1
  }
  next
}
{ stack = 0 }
END { exit ours }
