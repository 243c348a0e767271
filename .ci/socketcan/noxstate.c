/* LD_PRELOAD shim for linux.uml on hosts whose XSAVE area is larger than the buffer UML
   passes (CPUs with AMX: the host accepts an NT_X86_XSTATE register write only at its full
   size, about 11 KB, and UML panics at init with "ptrace set fp regs failed, errno = 14").
   It makes UML's PTRACE_GETREGSET/SETREGSET(NT_X86_XSTATE) calls fail, so UML falls back to
   PTRACE_GETFPREGS/SETFPREGS (the FXSAVE area: x87 and SSE state), which every host accepts.
   AVX state is then not preserved inside the guest: .ci/socketcan/run keeps glibc and OpenSSL
   on SSE code paths there and checks the result with vector-guard.c and known-answers.py
   before it runs anything (docs/socketcan.md). */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <errno.h>
#include <stdarg.h>
#include <sys/ptrace.h>
#include <sys/types.h>

#define NT_X86_XSTATE 0x202

long ptrace(enum __ptrace_request request, ...) {
    static long (*real_ptrace)(enum __ptrace_request, pid_t, void *, void *);
    va_list args;
    va_start(args, request);
    pid_t pid = va_arg(args, pid_t);
    void *addr = va_arg(args, void *);
    void *data = va_arg(args, void *);
    va_end(args);
    if ((request == PTRACE_GETREGSET || request == PTRACE_SETREGSET) &&
        (long)addr == NT_X86_XSTATE) {
        errno = EIO;
        return -1;
    }
    if (!real_ptrace) real_ptrace = (long (*)(enum __ptrace_request, pid_t, void *, void *))dlsym(RTLD_NEXT, "ptrace");
    return real_ptrace(request, pid, addr, data);
}
