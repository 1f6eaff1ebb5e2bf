/* Registry of potential laws.  A law is one const table in src/model/laws/;
 * adding a built-in law means adding its file and one line to `builtin` below.
 */
#include "model/model.h"

#include <string.h>

extern const mrvi_law mrvi_law_power;
extern const mrvi_law mrvi_law_linear;
extern const mrvi_law mrvi_law_morse;
extern const mrvi_law mrvi_law_lennard_jones;
extern const mrvi_law mrvi_law_inverse;

static const mrvi_law *const builtin[] = {
    &mrvi_law_power,         &mrvi_law_linear,  &mrvi_law_morse,
    &mrvi_law_lennard_jones, &mrvi_law_inverse,
};

#define N_BUILTIN ((int)(sizeof builtin / sizeof builtin[0]))
#define MAX_USER 64

static const mrvi_law *user[MAX_USER];
static int n_user = 0;

int mrvi_law_count(void) { return N_BUILTIN + n_user; }

const mrvi_law *mrvi_law_get(int i) {
  if (i < 0 || i >= mrvi_law_count())
    return NULL;
  return i < N_BUILTIN ? builtin[i] : user[i - N_BUILTIN];
}

const mrvi_law *mrvi_law_find(const char *name) {
  if (!name)
    return NULL;
  for (int i = 0; i < mrvi_law_count(); i++)
    if (strcmp(mrvi_law_get(i)->name, name) == 0)
      return mrvi_law_get(i);
  return NULL;
}

int mrvi_law_register(const mrvi_law *law) {
  if (!law || !law->name || !law->eval || law->n_params < 0 ||
      law->n_params > MRVI_LAW_MAX_PARAMS ||
      (law->n_params > 0 && !law->param_names))
    return MRVI_EINVAL;
  /* (a closed form reads its parameters: HOOKE one, POWER and MORSE two) */
  if ((law->form == MRVI_LAW_FORM_HOOKE && law->n_params < 1) ||
      ((law->form == MRVI_LAW_FORM_POWER || law->form == MRVI_LAW_FORM_MORSE) &&
       law->n_params < 2) ||
      (law->form != MRVI_LAW_FORM_NONE && law->form != MRVI_LAW_FORM_HOOKE &&
       law->form != MRVI_LAW_FORM_POWER && law->form != MRVI_LAW_FORM_MORSE))
    return MRVI_EINVAL;
  if (mrvi_law_find(law->name) || n_user == MAX_USER)
    return MRVI_EINVAL;
  user[n_user++] = law;
  return MRVI_OK;
}
