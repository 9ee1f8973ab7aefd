// Found only when there is no libtorch: .cargo/c++ (the C++ compiler of the build) adds this folder with
// -idirafter, searched after torch-sys's -I folders (<LIBTORCH>/include, ...). So when libtorch is missing,
// torch-sys's compile of its C++ glue stops here with what to do, not with "torch/torch.h: No such file".
#error "pointreggpt: no libtorch at LIBTORCH (third_party/libtorch, from .cargo/config.toml). Run `make libtorch` (a CPU libtorch 2.13.0 from PyPI wheels, once), or set LIBTORCH_USE_PYTORCH=1 (the PyTorch 2.13 of the active Python) or LIBTORCH=<a libtorch 2.13.0 folder>, then build again."
#include "libtorch-is-missing-see-the-error-above"
