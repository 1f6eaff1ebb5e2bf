/* Closest-name suggestions for misspelt keys, names and options ("did you
 * mean ...?"), shared by the description-file loader and the CLI. */
#include "util/util.h"

#include <string.h>

/* Levenshtein distance (names longer than 63 characters never match). */
static int edit_distance(const char *a, const char *b) {
  size_t la = strlen(a), lb = strlen(b);
  if (la > 63 || lb > 63)
    return 1 << 20;
  int row[64];
  for (size_t j = 0; j <= lb; j++)
    row[j] = (int)j;
  for (size_t i = 1; i <= la; i++) {
    int diag = row[0];
    row[0] = (int)i;
    for (size_t j = 1; j <= lb; j++) {
      int up = row[j];
      int best = diag + (a[i - 1] != b[j - 1]);
      if (up + 1 < best)
        best = up + 1;
      if (row[j - 1] + 1 < best)
        best = row[j - 1] + 1;
      row[j] = best;
      diag = up;
    }
  }
  return row[lb];
}

static int common_prefix(const char *a, const char *b) {
  int k = 0;
  while (a[k] && a[k] == b[k])
    k++;
  return k;
}

/* The candidate closest to `word` if it is close enough to be a likely typo;
 * ties go to the longer common prefix (micro_step: micro_steps, not
 * macro_step). */
const char *mrvi_closest(const char *word, const char *const *cand, int n) {
  const char *best = NULL;
  int best_d = 1 << 20, best_pre = -1;
  for (int i = 0; i < n; i++) {
    int d = edit_distance(word, cand[i]), pre = common_prefix(word, cand[i]);
    if (d < best_d || (d == best_d && pre > best_pre)) {
      best_d = d;
      best_pre = pre;
      best = cand[i];
    }
  }
  int len = (int)strlen(word);
  int limit = len / 3 > 2 ? len / 3 : 2;
  return best && best_d <= limit && best_d < len ? best : NULL;
}
