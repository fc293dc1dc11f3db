// Reads an ontology document with the OWL API (the library Protégé is built on, here the copy
// bundled in owlready2's HermiT.jar) and reports what Protégé users would trip over: triples the
// parser could not turn into axioms, and violations of the OWL 2 DL profile.
//
// Run (Java 11+ single-file launch, needs a JDK):
//   java -cp HermiT.jar OwlDlCheck.java <document> [<ontology IRI>=<local file> ...]
// The IRI=file pairs resolve owl:imports offline. Exit 0 and "OK <ontology> axioms=<n>" when clean,
// else 1 and one line per problem.

import java.io.File;
import java.util.Set;

import org.semanticweb.owlapi.apibinding.OWLManager;
import org.semanticweb.owlapi.io.RDFOntologyFormat;
import org.semanticweb.owlapi.io.RDFTriple;
import org.semanticweb.owlapi.model.IRI;
import org.semanticweb.owlapi.model.OWLOntology;
import org.semanticweb.owlapi.model.OWLOntologyFormat;
import org.semanticweb.owlapi.model.OWLOntologyManager;
import org.semanticweb.owlapi.profiles.OWL2DLProfile;
import org.semanticweb.owlapi.profiles.OWLProfileReport;
import org.semanticweb.owlapi.profiles.OWLProfileViolation;
import org.semanticweb.owlapi.util.SimpleIRIMapper;

public class OwlDlCheck {
    public static void main(String[] args) throws Exception {
        OWLOntologyManager manager = OWLManager.createOWLOntologyManager();
        for (int i = 1; i < args.length; i++) {
            String[] pair = args[i].split("=", 2);
            manager.addIRIMapper(new SimpleIRIMapper(IRI.create(pair[0]), IRI.create(new File(pair[1]))));
        }
        OWLOntology ontology = manager.loadOntologyFromOntologyDocument(new File(args[0]));
        int problems = 0;
        for (OWLOntology loaded : manager.getOntologies()) {
            OWLOntologyFormat format = manager.getOntologyFormat(loaded);
            if (format instanceof RDFOntologyFormat) {
                Set<RDFTriple> unparsed =
                    ((RDFOntologyFormat) format).getOntologyLoaderMetaData().getUnparsedTriples();
                for (RDFTriple triple : unparsed) {
                    System.out.println("UNPARSED " + triple);
                    problems++;
                }
            }
        }
        OWLProfileReport report = new OWL2DLProfile().checkOntology(ontology);
        for (OWLProfileViolation violation : report.getViolations()) {
            System.out.println("NOT-DL " + violation);
            problems++;
        }
        if (problems > 0) {
            System.exit(1);
        }
        System.out.println("OK " + ontology.getOntologyID() + " axioms=" + ontology.getAxiomCount());
    }
}
