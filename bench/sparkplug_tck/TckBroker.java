// An embedded HiveMQ CE broker on 127.0.0.1 with the Eclipse Sparkplug TCK extension loaded in
// process and an authenticator that lets every client in (the TCK's own instructions install
// hivemq-allow-all-extension for that). Started by bench/sparkplug_tck.py; not part of fieldgate.
//
//   java -cp <hivemq embedded + TCK jars> TckBroker WORK_DIR PORT HOST_ID
//
// Prints "console client id: <id>", then "TCK broker ready" once the listener accepts clients;
// stops on SIGTERM.
//
// The console client id: HiveMQ runs each client's extension tasks (interceptors) on one of a
// fixed set of threads, chosen by a hash of its client id (BucketUtils.getBucket). The TCK
// handles NEW_TEST inside the publish interceptor of the console's client and, in there,
// connects its simulated host application ("Sparkplug_TCK_<host id>", and "..._WRONG" in
// PrimaryHostTest) to this broker and waits for the CONNACK; that CONNECT's own interceptor
// task waits for its thread. When both client ids hash to the same thread, the TCK deadlocks
// (seen with 2 cores: PrimaryHostTest hung in HostApplication.hostPrepare). So this launcher
// gives HiveMQ 8 such threads (HiveMQ takes one per core: with 2, the two host ids take both)
// and prints a console id that shares no thread with those.

import com.hivemq.embedded.EmbeddedExtension;
import com.hivemq.embedded.EmbeddedHiveMQ;
import com.hivemq.extension.sdk.api.ExtensionMain;
import com.hivemq.extension.sdk.api.auth.SimpleAuthenticator;
import com.hivemq.extension.sdk.api.parameter.ExtensionStartInput;
import com.hivemq.extension.sdk.api.parameter.ExtensionStartOutput;
import com.hivemq.extension.sdk.api.parameter.ExtensionStopInput;
import com.hivemq.extension.sdk.api.parameter.ExtensionStopOutput;
import com.hivemq.extension.sdk.api.services.Services;
import java.nio.file.Files;
import java.nio.file.Path;
import java.util.List;
import java.util.concurrent.CountDownLatch;
import org.eclipse.sparkplug.tck.SparkplugHiveMQExtension;

public final class TckBroker {
    /** The TCK extension, plus an allow-all authenticator (HiveMQ refuses clients without one). */
    static final class Main implements ExtensionMain {
        private final SparkplugHiveMQExtension tck = new SparkplugHiveMQExtension();

        @Override
        public void extensionStart(ExtensionStartInput in, ExtensionStartOutput out) {
            Services.securityRegistry()
                    .setAuthenticatorProvider(
                            input -> (SimpleAuthenticator) (connect, result) -> result.authenticateSuccessfully());
            tck.extensionStart(in, out);
        }

        @Override
        public void extensionStop(ExtensionStopInput in, ExtensionStopOutput out) {
            tck.extensionStop(in, out);
        }
    }

    public static void main(String[] args) throws Exception {
        Path work = Path.of(args[0]);
        int port = Integer.parseInt(args[1]);
        String hostId = args[2];
        com.hivemq.configuration.service.InternalConfigurations
                .EXTENSION_TASK_QUEUE_EXECUTOR_THREADS_COUNT.set(8);
        Path conf = Files.createDirectories(work.resolve("conf"));
        Files.writeString(
                conf.resolve("config.xml"),
                "<hivemq><listeners><tcp-listener><port>" + port + "</port>"
                        + "<bind-address>127.0.0.1</bind-address></tcp-listener></listeners>"
                        + "<anonymous-usage-statistics><enabled>false</enabled></anonymous-usage-statistics>"
                        + "</hivemq>\n");
        EmbeddedExtension extension = EmbeddedExtension.builder()
                .withId("sparkplug-tck")
                .withName("Eclipse Sparkplug TCK")
                .withVersion("3.0.0")
                .withAuthor("Eclipse")
                .withPriority(0)
                .withStartPriority(1000)
                .withExtensionMain(new Main())
                .build();
        EmbeddedHiveMQ hivemq = EmbeddedHiveMQ.builder()
                .withConfigurationFolder(conf)
                .withDataFolder(Files.createDirectories(work.resolve("data")))
                .withExtensionsFolder(Files.createDirectories(work.resolve("extensions")))
                .withEmbeddedExtension(extension)
                .build();
        CountDownLatch stopped = new CountDownLatch(1);
        Runtime.getRuntime().addShutdownHook(new Thread(() -> {
            try {
                hivemq.stop().join();
            } catch (Exception e) {
                // stopping anyway
            }
            stopped.countDown();
        }));
        hivemq.start().join();
        int threads = com.hivemq.configuration.service.InternalConfigurations
                .EXTENSION_TASK_QUEUE_EXECUTOR_THREADS_COUNT.get();
        List<String> tckClients = List.of("Sparkplug_TCK_" + hostId, "Sparkplug_TCK_" + hostId + "_WRONG");
        String console = null;
        for (int i = 0; console == null && i < 1000; i++) {
            String candidate = "fieldgate-tck-console-" + i;
            int bucket = com.hivemq.persistence.local.xodus.bucket.BucketUtils.getBucket(candidate, threads);
            if (tckClients.stream().noneMatch(
                    c -> com.hivemq.persistence.local.xodus.bucket.BucketUtils.getBucket(c, threads) == bucket)) {
                console = candidate;
            }
        }
        if (console == null) {
            throw new IllegalStateException(threads + " extension threads: no console id avoids the TCK's");
        }
        System.out.println("extension task threads: " + threads);
        System.out.println("console client id: " + console);
        System.out.println("TCK broker ready");
        System.out.flush();
        stopped.await();
    }
}
